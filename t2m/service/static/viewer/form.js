/** The form: segment rows, POST /generate (streamed), downloads. */
import { $, ui, state } from './state.js';
import { beginMotion, appendFrames, finishMotion } from './playback.js';
import { refreshEditPanel } from './editing.js';

export function addRow(text = '', duration = 3) {
  const row = ui.rowTemplate.content.firstElementChild.cloneNode(true);
  row.querySelector('.seg-text').value = text;
  row.querySelector('.seg-duration').value = duration === null ? '' : String(duration);
  row.querySelector('.remove-row').addEventListener('click', () => {
    if (ui.rows.children.length > 1) row.remove();
    else row.querySelector('.seg-text').value = '';
  });
  ui.rows.appendChild(row);
  return row;
}

export function readNumber(input) {
  const raw = input.value.trim();
  if (raw === '') return null;
  const value = Number(raw);
  return Number.isFinite(value) ? value : NaN;
}

/** The request body from the form; throws with the field named when something is plainly missing. */
export function buildRequest(format) {
  clearInvalid();
  const segments = Array.from(ui.rows.children).map((row, i) => {
    const textInput = row.querySelector('.seg-text');
    const durationInput = row.querySelector('.seg-duration');
    const text = textInput.value.trim();
    if (!text) throw fieldError(textInput, `sentence ${i + 1}: the text is empty`);
    const duration = readNumber(durationInput);
    if (Number.isNaN(duration)) throw fieldError(durationInput, `sentence ${i + 1}: the duration is not a number`);
    const segment = { text };
    if (duration !== null) segment.duration = duration;
    return segment;
  });
  const body = { segments, format };
  if (!ui.modelField.hidden && ui.model.value) body.model = ui.model.value;
  for (const [key, input] of [['seed', ui.seed], ['guidance', ui.guidance], ['temperature', ui.temperature], ['top_k', ui.topK]]) {
    const value = readNumber(input);
    if (Number.isNaN(value)) throw fieldError(input, `${key} is not a number`);
    if (value !== null) body[key] = value;
  }
  return body;
}

export function fieldError(input, message) {
  input.classList.add('invalid');
  input.focus();
  return new Error(message);
}

export function clearInvalid() {
  document.querySelectorAll('.invalid').forEach((el) => el.classList.remove('invalid'));
}

/** Marks the input a 422 error points at (loc like ["body", "segments", 1, "duration"]). */
export function markFromLocation(loc) {
  const path = loc[0] === 'body' ? loc.slice(1) : loc;
  if (path[0] === 'edits') { // an edit sent from the edit bar: its text is the field the person can change
    if (path.includes('text')) ui.editText.classList.add('invalid');
    return;
  }
  if (path[0] === 'segments' && Number.isInteger(path[1])) {
    const row = ui.rows.children[path[1]];
    const input = row && row.querySelector(path[2] === 'duration' ? '.seg-duration' : '.seg-text');
    if (input) input.classList.add('invalid');
    return;
  }
  const byField = {
    seed: ui.seed, guidance: ui.guidance, temperature: ui.temperature, top_k: ui.topK, model: ui.model,
  };
  if (byField[path[0]]) byField[path[0]].classList.add('invalid');
}

export function showMessage(text, kind = '') {
  ui.message.textContent = text;
  ui.message.className = `message ${kind}`;
}

/** The model's warnings for the motion on screen (e.g. a sentence far from everything it was trained on). */
export function showWarnings(warnings) {
  ui.warnings.replaceChildren(...(warnings || []).map((text) => {
    const item = document.createElement('li');
    item.textContent = text;
    return item;
  }));
  ui.warnings.hidden = !(warnings && warnings.length);
}

/** A readable sentence for a failed response: names the fields (422), the wait (429), or the status. */
export async function describeFailure(response) {
  let body = null;
  try {
    body = await response.json();
  } catch (_) {
    // not JSON; fall back to the status line
  }
  const detail = body && body.detail;
  if (response.status === 422 && Array.isArray(detail)) {
    detail.forEach((d) => Array.isArray(d.loc) && markFromLocation(d.loc));
    return detail
      .map((d) => `${(d.loc || []).filter((p) => p !== 'body').join('.')}: ${d.msg}`)
      .join('\n');
  }
  if (response.status === 429) {
    const wait = response.headers.get('Retry-After');
    return `The server is busy${wait ? `; try again in ${wait} s` : '; try again shortly'}.`;
  }
  if (response.status === 503) return 'The model is still loading; try again in a moment.';
  if (response.status === 401 || response.status === 403) {
    ui.apiKey.closest('details').open = true;
    ui.apiKey.classList.add('invalid');
    return 'This server needs an API key: enter it under "API key".';
  }
  const text = typeof detail === 'string' ? detail : detail ? JSON.stringify(detail) : response.statusText;
  return `Request failed (${response.status}): ${text}`;
}

/** Calls onMessage with each message of a streamed answer (newline-delimited JSON) as its line arrives. */
export async function readMessages(response, onMessage) {
  const reader = response.body.getReader();
  const decoder = new TextDecoder();
  let buffered = '';
  for (;;) {
    const { value, done } = await reader.read();
    buffered += decoder.decode(value || new Uint8Array(), { stream: !done });
    const lines = buffered.split('\n');
    buffered = done ? '' : lines.pop();
    lines.filter((line) => line.trim()).forEach((line) => onMessage(JSON.parse(line)));
    if (done) return;
  }
}

/** Plays a streamed motion as it arrives; resolves with the end message (throws on an error message). */
export async function playStream(response, body) {
  let motion = null;
  let end = null;
  await readMessages(response, (message) => {
    if (message.type === 'start') {
      motion = { fps: message.fps, joints: message.joints, parents: message.parents, model: message.model,
        seed: message.seed, frames: [], segments: [], warnings: [] };
    } else if (message.type === 'frames' && motion) {
      if (motion.frames.length) {
        appendFrames(message.frames);
      } else {
        motion.frames.push(...message.frames);
        beginMotion(motion, { ...body, seed: motion.seed });
      }
    } else if (message.type === 'end' && motion && motion.frames.length) {
      end = message;
      finishMotion(message);
    } else if (message.type === 'error') {
      throw new Error(`${message.detail} (${message.status})`);
    } else {
      throw new Error(`the server answered with an unexpected stream message (${message.type})`);
    }
  });
  if (!end) throw new Error('the answer ended before the whole motion arrived');
  return end;
}

export async function postJson(path, body) {
  const headers = { 'Content-Type': 'application/json' };
  const key = ui.apiKey.value.trim();
  if (key) headers.Authorization = `Bearer ${key}`;
  return fetch(path, { method: 'POST', headers, body: JSON.stringify(body) });
}

export const postGenerate = (body) => postJson('generate', body);

export async function onGenerate(event) {
  event.preventDefault();
  let body;
  try {
    body = buildRequest('json');
  } catch (err) {
    showMessage(err.message, 'error');
    return;
  }
  ui.generate.disabled = true;
  state.busy = true; // no edit meanwhile: its answer would race this one
  refreshEditPanel();
  document.body.dataset.state = 'loading';
  showMessage('Generating…');
  showWarnings([]);
  const started = performance.now();
  try {
    const response = await postGenerate({ ...body, stream: true });
    if (!response.ok) {
      showMessage(await describeFailure(response), 'error');
      document.body.dataset.state = 'error';
      return;
    }
    const firstFrames = ((performance.now() - started) / 1000).toFixed(2); // sent with the first frames
    const end = await playStream(response, body);
    showWarnings(end.warnings);
    const seconds = ((performance.now() - started) / 1000).toFixed(2);
    showMessage(`${end.frame_count} frames (${(end.frame_count / end.fps).toFixed(1)} s of motion) in ${seconds} s, ` +
      `first frames after ${firstFrames} s · seed ${end.seed}`, 'ok');
  } catch (err) {
    state.streaming = false; // what arrived of a broken stream loops like a whole motion
    showMessage(`Could not generate: ${err.message}`, 'error');
    document.body.dataset.state = 'error';
  } finally {
    ui.generate.disabled = false;
    state.busy = false;
    refreshEditPanel();
  }
}

export function filenameFrom(response, fallback) {
  const disposition = response.headers.get('Content-Disposition') || '';
  const match = /filename\*?=(?:UTF-8'')?"?([^";]+)"?/i.exec(disposition);
  return match ? decodeURIComponent(match[1]) : fallback;
}

/** Asks for the shown motion again in another format (same request, same seed; an edited motion: its handle
 * with no edits, the same motion bit for bit) and saves the file. */
export async function download(format, button) {
  if (!state.request && !state.handle) return;
  button.disabled = true;
  try {
    const response = state.request ? await postGenerate({ ...state.request, format })
      : await postJson('edit', { handle: state.handle, edits: [], format });
    if (!response.ok) {
      showMessage(await describeFailure(response), 'error');
      return;
    }
    const blob = await response.blob();
    const name = filenameFrom(response, `motion.${format}`);
    const url = URL.createObjectURL(blob);
    const link = document.createElement('a');
    link.href = url;
    link.download = name;
    document.body.appendChild(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(url), 30000);
    document.body.dataset.lastDownload = `${name}:${blob.size}`;
    showMessage(`Saved ${name} (${(blob.size / 1024).toFixed(1)} KiB).`, 'ok');
  } catch (err) {
    showMessage(`Could not download: ${err.message}`, 'error');
  } finally {
    button.disabled = false;
  }
}
