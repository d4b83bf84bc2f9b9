/** Editing a segment of the shown motion through POST /edit with its handle. */
import { $, ui, state } from './state.js';
import { setFrame, beginMotion, finishMotion } from './playback.js';
import { fieldError, clearInvalid, showMessage, showWarnings, describeFailure, postJson } from './form.js';

/** The edit kinds (GET /health `extra.edits`) of the model that made the motion shown. */
export function editKinds() {
  const name = state.motion && state.motion.model && state.motion.model.name;
  const model = state.models.find((m) => m.name === name);
  const kinds = model && model.extra && model.extra.edits;
  return Array.isArray(kinds) ? kinds : [];
}

/** Selects segment `index` of the motion shown (-1: none) and puts its text in the edit bar. */
export function selectSegment(index) {
  const segments = (state.motion && state.motion.segments) || [];
  state.selected = index >= 0 && index < segments.length ? index : -1;
  Array.from(ui.strip.children).forEach((el, i) => el.classList.toggle('selected', i === state.selected));
  ui.editText.value = state.selected >= 0 ? segments[state.selected].text : '';
  ui.editText.classList.remove('invalid');
  document.body.dataset.selected = String(state.selected);
  refreshEditPanel();
}

/** Enables what can be sent now: a selected segment of a whole motion with a handle, kinds the model supports. */
export function refreshEditPanel() {
  const motion = state.motion;
  const segments = (motion && motion.segments) || [];
  const index = state.selected;
  const selected = index >= 0 && index < segments.length;
  const kinds = editKinds();
  const regenerates = kinds.includes('regenerate');
  const bodyParts = kinds.includes('body_part');
  const ready = Boolean(state.handle) && !state.streaming && !state.busy;
  if (state.handle) ui.editPanel.hidden = false;
  const name = (motion && motion.model && motion.model.name) || 'this model';
  if (!regenerates && !bodyParts) {
    ui.editTitle.textContent = `${name} cannot edit a motion`;
  } else if (selected) {
    const s = segments[index];
    ui.editTitle.textContent = `segment ${index + 1} of ${segments.length} · frames ${s.start_frame}–${s.end_frame - 1}`;
  } else {
    ui.editTitle.textContent = 'click a segment on the timeline to edit it';
  }
  if (!bodyParts) ui.editUpper.checked = false;
  ui.editUpper.disabled = !(ready && selected && bodyParts);
  const upperLabel = ui.editUpper.closest('label');
  upperLabel.classList.toggle('unsupported', !bodyParts);
  upperLabel.title = bodyParts ? 'regenerate only the upper body\'s joints over this segment'
    : `${name} cannot regenerate a body part (GET /health: its extra.edits)`;
  const sendable = ready && selected && (ui.editUpper.checked ? bodyParts : regenerates);
  ui.editText.disabled = !(ready && selected && (regenerates || bodyParts));
  ui.editRegenerate.disabled = !sendable;
  ui.editReroll.disabled = !sendable;
  document.body.dataset.editKinds = kinds.join(',');
}

/** POST /edit: the selected segment again (its new text; a new random seed on a re-roll; only the upper body). */
export async function onEdit(reroll) {
  const motion = state.motion;
  const index = state.selected;
  if (!motion || !state.handle || state.busy || index < 0 || index >= motion.segments.length) return;
  clearInvalid();
  const text = ui.editText.value.trim();
  if (!text) {
    showMessage(fieldError(ui.editText, `segment ${index + 1}: the text is empty`).message, 'error');
    return;
  }
  const edit = ui.editUpper.checked ? { op: 'body_part', segment: index, part: 'upper_body' } : { segment: index };
  if (text !== motion.segments[index].text) edit.text = text;
  if (reroll) edit.seed = Math.floor(Math.random() * 2 ** 31);
  state.busy = true;
  ui.generate.disabled = true;
  refreshEditPanel();
  document.body.dataset.state = 'loading';
  showMessage(`Regenerating segment ${index + 1}…`);
  const started = performance.now();
  try {
    const response = await postJson('edit', { handle: state.handle, edits: [edit], format: 'json' });
    if (!response.ok) {
      showMessage(await describeFailure(response), 'error');
      document.body.dataset.state = 'error';
      return;
    }
    const answer = await response.json();
    showEdited(answer, index);
    showWarnings(answer.warnings);
    const seconds = ((performance.now() - started) / 1000).toFixed(2);
    const seeds = (answer.edited || []).map((e) => `segment ${e.segment + 1} seed ${e.seed}`).join(', ');
    showMessage(`Edited: ${seeds || `segment ${index + 1}`}${edit.op ? ' (upper body)' : ''} · ` +
      `${answer.frames.length} frames in ${seconds} s`, 'ok');
    document.body.dataset.edits = String(Number(document.body.dataset.edits || 0) + 1);
  } catch (err) {
    showMessage(`Could not edit: ${err.message}`, 'error');
    document.body.dataset.state = 'error';
  } finally {
    state.busy = false;
    ui.generate.disabled = false;
    refreshEditPanel();
  }
}

/** The edited motion (a json answer) replaces the shown one and plays from a second before the edited segment. */
export function showEdited(answer, index) {
  const motion = { fps: answer.fps, joints: answer.joints, parents: answer.parents, model: answer.model,
    seed: answer.seed, frames: answer.frames, segments: [], warnings: [] };
  beginMotion(motion, null);
  finishMotion(answer);
  const segment = motion.segments[index];
  if (segment) {
    setFrame(Math.max(0, segment.start_frame - motion.fps));
    state.clock = state.frame / motion.fps;
  }
}
