/** Playing a motion (streamed or whole): the clock, the frame, the timeline of segments. */
import { SEGMENT_COLORS, $, ui, state, clamp } from './state.js';
import { render } from './drawing.js';
import { selectSegment, refreshEditPanel } from './editing.js';

export function setFrame(frame) {
  const motion = state.motion;
  if (!motion) return;
  const total = motion.frames.length;
  frame = ((frame % total) + total) % total;
  if (frame === state.frame) return;
  state.frame = frame;
  ui.slider.value = String(frame);
  ui.frameLabel.textContent = `${frame + 1} / ${total} · ${(frame / motion.fps).toFixed(2)} s`;
  document.body.dataset.frame = String(frame);
  ui.playhead.style.left = `${(100 * frame) / total}%`;
  showSegmentAt(frame);
}

export function showSegmentAt(frame) {
  const segments = state.motion.segments || [];
  let index = segments.findIndex((s) => frame >= s.start_frame && frame < s.end_frame);
  if (index < 0 && segments.length && frame >= segments[segments.length - 1].start_frame) index = segments.length - 1;
  if (index === state.currentSegment) return;
  state.currentSegment = index;
  ui.caption.hidden = index < 0;
  ui.caption.textContent = index >= 0 ? segments[index].text : '';
  ui.caption.style.borderColor = index >= 0 ? SEGMENT_COLORS[index % SEGMENT_COLORS.length] : '';
  Array.from(ui.strip.children).forEach((el, i) => el.classList.toggle('current', i === index));
}

export function setPlaying(playing) {
  state.playing = playing;
  ui.play.textContent = playing ? 'Pause' : 'Play';
  if (state.motion) state.clock = state.frame / state.motion.fps;
}

export function followTarget(dt) {
  if (!state.motion || !ui.follow.checked) return;
  const pelvis = state.motion.frames[state.frame][0];
  const t = state.camera.target;
  const k = Math.min(1, dt * 5);
  t[0] += (pelvis[0] - t[0]) * k;
  t[2] += (pelvis[2] - t[2]) * k;
  // Snap when close, so a paused picture comes to rest instead of creeping for ever.
  if (Math.hypot(pelvis[0] - t[0], pelvis[2] - t[2]) < 0.005) {
    t[0] = pelvis[0];
    t[2] = pelvis[2];
  }
}

export function tick(now) {
  const dt = state.lastTick === null ? 0 : Math.min(0.1, (now - state.lastTick) / 1000);
  state.lastTick = now;
  if (state.motion && state.playing) {
    state.clock += dt;
    setFrame(playbackFrame());
  }
  followTarget(dt);
  render();
  window.requestAnimationFrame(tick);
}

/** The frame the clock points at: looping once the motion is whole, waiting at the newest frame while it streams. */
export function playbackFrame() {
  const motion = state.motion;
  const available = motion.frames.length;
  const frame = Math.floor(state.clock * motion.fps);
  if (!state.streaming) return frame % available;
  if (frame < available) return frame;
  state.clock = (available - 1) / motion.fps;
  return available - 1;
}

/** Starts playing a motion whose first frames have arrived (appendFrames adds the next, finishMotion the rest). */
export function beginMotion(motion, request) {
  const frames = motion.frames;
  const parents = motion.parents;
  if (!Array.isArray(frames) || !frames.length || !Array.isArray(parents) || frames[0].length !== parents.length) {
    throw new Error('the server answered with an unexpected motion layout');
  }
  state.motion = motion;
  state.streaming = true;
  state.request = request;
  state.sides = (motion.joints || []).map((name) =>
    /^(left|l_)/i.test(name) ? 'left' : /^(right|r_)/i.test(name) ? 'right' : 'centre');
  state.headJoint = (motion.joints || []).indexOf('head');
  state.frame = -1;
  state.currentSegment = -2;
  state.clock = 0;
  // Aim at the body's middle: the median pelvis height (about 0.9 m standing; lower for a crawl or a sit).
  const heights = frames.map((f) => f[0][1]).sort((x, y) => x - y);
  const start = frames[0][0];
  state.camera.target = [start[0], clamp(heights[heights.length >> 1], 0.3, 1.3), start[2]];

  ui.slider.max = String(frames.length - 1);
  ui.slider.disabled = false;
  ui.play.disabled = false;
  ui.strip.replaceChildren();
  ui.playhead.hidden = false;
  setFrame(0);
  setPlaying(true);
  ui.downloadBvh.disabled = true;
  ui.downloadGlb.disabled = true;
  const model = motion.model || {};
  ui.modelInfo.textContent = model.name ? `model ${model.name} ${model.version || ''}` : '';
  document.body.dataset.frames = String(frames.length);
  document.body.dataset.framesAtStart = String(frames.length);
  document.body.dataset.state = 'streaming';
  state.handle = null; // no edits until the motion has arrived whole (finishMotion: its handle)
  document.body.dataset.handle = '';
  if (request) selectSegment(-1); // a new generation; an edit keeps the selected segment
  else refreshEditPanel();
}

export function appendFrames(frames) {
  state.motion.frames.push(...frames);
  ui.slider.max = String(state.motion.frames.length - 1);
  document.body.dataset.frames = String(state.motion.frames.length);
}

/** The stream's end message: the sentences' spans, the warnings; the motion now loops and can be downloaded. */
export function finishMotion(end) {
  const motion = state.motion;
  motion.segments = end.segments || [];
  motion.warnings = end.warnings || [];
  state.streaming = false;
  state.currentSegment = -2;
  state.handle = end.handle || null;
  document.body.dataset.handle = state.handle || '';
  if (state.selected >= motion.segments.length) state.selected = -1;
  buildSegmentStrip(motion.segments, motion.frames.length);
  showSegmentAt(Math.max(state.frame, 0));
  selectSegment(state.selected);
  ui.downloadBvh.disabled = false;
  ui.downloadGlb.disabled = false;
  document.body.dataset.state = 'ready';
}

/** The timeline: one block per segment, its width its share of the frames (the playhead moves over them). */
export function buildSegmentStrip(segments, total) {
  ui.strip.replaceChildren();
  const width = (frames) => `${(100 * Math.max(0, frames)) / Math.max(1, total)}%`;
  segments.forEach((s, i) => {
    const span = document.createElement('span');
    span.style.width = width(s.end_frame - s.start_frame);
    span.style.background = SEGMENT_COLORS[i % SEGMENT_COLORS.length];
    span.textContent = s.text;
    span.title = `${s.text} (frames ${s.start_frame}–${s.end_frame - 1}): click to edit`;
    span.addEventListener('click', () => {
      selectSegment(i);
      setFrame(s.start_frame);
      state.clock = state.frame / state.motion.fps;
    });
    ui.strip.appendChild(span);
  });
  const covered = segments.length ? segments[segments.length - 1].end_frame : 0;
  if (covered < total) {
    const rest = document.createElement('span');
    rest.className = 'rest';
    rest.style.width = width(total - covered);
    ui.strip.appendChild(rest);
  }
}
