/*
 * t2m viewer: a form that POSTs /generate and a small 3D skeleton player.
 *
 * Everything is drawn on a 2D canvas with our own perspective projection (a pinhole camera orbiting a target),
 * so the page needs no WebGL, no libraries and no network beyond this service. The answer is streamed ("stream":
 * true, newline-delimited JSON): playback starts with the first frames and waits at the newest frame for the next.
 * The page reports its state on <body data-state data-frames data-frame data-frames-at-start> (state: loading,
 * streaming, ready, error) so scripts and tests can follow it without scraping the UI.
 *
 * Under the player, the timeline shows the motion's segments (one block per segment, as wide as its frames). A click
 * selects one; the edit bar then regenerates it (a new text, or a new random seed; just the upper body where the model
 * inpaints body parts) through POST /edit with the last answer's handle, and the edited motion replaces the shown one
 * (its new handle kept for the next edit). <body data-handle data-selected data-edits> report the handle of the
 * motion shown, the selection and the edits made.
 */
(function () {
  'use strict';

  // ---------------------------------------------------------------- constants

  const FIELD_OF_VIEW = (50 * Math.PI) / 180; // vertical
  const NEAR = 0.05; // metres; lines are clipped here so nothing behind the camera is drawn
  const GRID_HALF = 8; // metres of floor grid on each side of the camera target
  const PITCH_LIMITS = [0.03, 1.45];
  const DISTANCE_LIMITS = [1.2, 30];
  const SEGMENT_COLORS = ['#4fa3ff', '#f5a35c', '#6fd49a', '#e07bd4', '#f0d35a', '#7fd6e0', '#ff8a8a', '#b39ddb'];
  const SIDE_COLORS = { left: '#4fa3ff', right: '#f5a35c', centre: '#e3e6eb' };
  const DEFAULT_ROWS = [
    ['a person walks forward', 3],
    ['a person turns around and waves', 3],
  ];

  // ---------------------------------------------------------------- elements and state

  const $ = (id) => document.getElementById(id);
  const ui = {
    form: $('generate-form'),
    rows: $('segment-rows'),
    rowTemplate: $('segment-row-template'),
    addRow: $('add-row'),
    seed: $('seed'),
    guidance: $('guidance'),
    temperature: $('temperature'),
    topK: $('top-k'),
    model: $('model'),
    modelField: $('model-field'),
    apiKey: $('api-key'),
    generate: $('generate'),
    message: $('message'),
    warnings: $('warnings'),
    downloadBvh: $('download-bvh'),
    downloadGlb: $('download-glb'),
    modelInfo: $('model-info'),
    serverStatus: $('server-status'),
    canvas: $('view'),
    caption: $('caption'),
    play: $('play'),
    slider: $('frame-slider'),
    strip: $('segment-strip'),
    frameLabel: $('frame-label'),
    follow: $('follow'),
    playhead: $('playhead'),
    editPanel: $('edit-panel'),
    editTitle: $('edit-title'),
    editText: $('edit-text'),
    editUpper: $('edit-upper'),
    editRegenerate: $('edit-regenerate'),
    editReroll: $('edit-reroll'),
  };
  const ctx = ui.canvas.getContext('2d');

  const state = {
    motion: null, // the motion being shown: the json answer's fields, its frames growing while it streams
    streaming: false, // more frames are on their way
    request: null, // the /generate request body that produced it, with the seed the server used (null: an edit)
    handle: null, // the last json answer's handle: what POST /edit takes (null while streaming or none)
    selected: -1, // the segment selected on the timeline for editing
    busy: false, // a generation or an edit is on its way (no edit meanwhile)
    playing: true,
    clock: 0, // seconds into the motion
    frame: -1,
    lastTick: null,
    camera: { yaw: 0.55, pitch: 0.28, distance: 4.6, target: [0, 0.9, 0] },
    drag: null,
    sides: [], // 'left' | 'right' | 'centre' per joint
    headJoint: -1,
    currentSegment: -1,
    models: [], // GET /health `models`: every model the server serves, the default first
  };

  // ---------------------------------------------------------------- small vector helpers

  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const normalize = (a) => scale(a, 1 / Math.hypot(a[0], a[1], a[2]));
  const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));

  // ---------------------------------------------------------------- camera and projection

  /** The camera basis for this frame: eye on a sphere around the target, looking at it, Y up. */
  function makeView(width, height) {
    const cam = state.camera;
    const cp = Math.cos(cam.pitch);
    const towardEye = [cp * Math.sin(cam.yaw), Math.sin(cam.pitch), cp * Math.cos(cam.yaw)];
    const eye = add(cam.target, scale(towardEye, cam.distance));
    const forward = scale(towardEye, -1);
    const right = normalize(cross(forward, [0, 1, 0]));
    const up = cross(right, forward);
    const focal = (0.5 * height) / Math.tan(FIELD_OF_VIEW / 2);
    return { eye, forward, right, up, focal, cx: width / 2, cy: height / 2 };
  }

  /** World point -> camera coordinates (x right, y up, z = depth along the view direction). */
  function toCamera(view, p) {
    const d = sub(p, view.eye);
    return [dot(d, view.right), dot(d, view.up), dot(d, view.forward)];
  }

  /** Camera coordinates -> canvas pixels (only for depth >= NEAR). */
  function toScreen(view, c) {
    return [view.cx + (view.focal * c[0]) / c[2], view.cy - (view.focal * c[1]) / c[2]];
  }

  /** Clips a camera-space segment against the near plane; null when it lies wholly behind it. */
  function clipNear(a, b) {
    if (a[2] < NEAR && b[2] < NEAR) return null;
    if (a[2] >= NEAR && b[2] >= NEAR) return [a, b];
    const t = (NEAR - a[2]) / (b[2] - a[2]);
    const hit = [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, NEAR];
    return a[2] < NEAR ? [hit, b] : [a, hit];
  }

  function strokeSegment(view, a, b) {
    const clipped = clipNear(toCamera(view, a), toCamera(view, b));
    if (!clipped) return;
    const p = toScreen(view, clipped[0]);
    const q = toScreen(view, clipped[1]);
    ctx.beginPath();
    ctx.moveTo(p[0], p[1]);
    ctx.lineTo(q[0], q[1]);
    ctx.stroke();
  }

  // ---------------------------------------------------------------- drawing

  function resizeCanvas() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(ui.canvas.clientWidth * dpr));
    const h = Math.max(1, Math.round(ui.canvas.clientHeight * dpr));
    if (ui.canvas.width !== w || ui.canvas.height !== h) {
      ui.canvas.width = w;
      ui.canvas.height = h;
    }
    return dpr;
  }

  function drawBackground(w, h) {
    const sky = ctx.createLinearGradient(0, 0, 0, h);
    sky.addColorStop(0, '#1d232c');
    sky.addColorStop(1, '#0f1215');
    ctx.fillStyle = sky;
    ctx.fillRect(0, 0, w, h);
  }

  /** A 1 m floor grid around the target, fading with distance so its edge does not show. */
  function drawGrid(view, dpr) {
    const t = state.camera.target;
    const cx = Math.round(t[0]);
    const cz = Math.round(t[2]);
    ctx.lineWidth = 1 * dpr;
    for (let i = -GRID_HALF; i <= GRID_HALF; i++) {
      for (let k = -GRID_HALF; k < GRID_HALF; k++) {
        // One metre piece of the line x = cx + i and one of the line z = cz + i.
        const fade = 1 - Math.hypot(i, k + 0.5) / (GRID_HALF + 0.5);
        if (fade <= 0) continue;
        const major = (cx + i) % 5 === 0;
        ctx.strokeStyle = `rgba(150, 165, 185, ${(major ? 0.42 : 0.22) * fade})`;
        strokeSegment(view, [cx + i, 0, cz + k], [cx + i, 0, cz + k + 1]);
        const majorZ = (cz + i) % 5 === 0;
        ctx.strokeStyle = `rgba(150, 165, 185, ${(majorZ ? 0.42 : 0.22) * fade})`;
        strokeSegment(view, [cx + k, 0, cz + i], [cx + k + 1, 0, cz + i]);
      }
    }
  }

  /** The pelvis path on the floor: the whole path faint, the part already played brighter. */
  function drawTrajectory(view, frames, upTo, dpr) {
    ctx.lineWidth = 2 * dpr;
    for (let f = 1; f < frames.length; f++) {
      const a = frames[f - 1][0];
      const b = frames[f][0];
      ctx.strokeStyle = f <= upTo ? 'rgba(79, 163, 255, 0.55)' : 'rgba(79, 163, 255, 0.16)';
      strokeSegment(view, [a[0], 0.002, a[2]], [b[0], 0.002, b[2]]);
    }
  }

  function drawSkeleton(view, joints, parents, dpr) {
    ctx.lineCap = 'round';
    const cam = joints.map((p) => toCamera(view, p));

    // Shadow: the bones flattened onto the floor.
    ctx.strokeStyle = 'rgba(0, 0, 0, 0.35)';
    for (let j = 0; j < parents.length; j++) {
      const p = parents[j];
      if (p < 0) continue;
      const a = joints[j];
      const b = joints[p];
      const depth = toCamera(view, [a[0], 0, a[2]])[2];
      ctx.lineWidth = Math.max(1, (0.05 * view.focal) / Math.max(depth, NEAR));
      strokeSegment(view, [a[0], 0.001, a[2]], [b[0], 0.001, b[2]]);
    }

    // Bones far to near, so nearer limbs cover farther ones.
    const bones = [];
    for (let j = 0; j < parents.length; j++) {
      if (parents[j] >= 0) bones.push({ j, p: parents[j], depth: (cam[j][2] + cam[parents[j]][2]) / 2 });
    }
    bones.sort((x, y) => y.depth - x.depth);
    for (const bone of bones) {
      if (bone.depth < NEAR) continue;
      ctx.strokeStyle = SIDE_COLORS[state.sides[bone.j]] || SIDE_COLORS.centre;
      ctx.lineWidth = Math.max(1.5 * dpr, (0.05 * view.focal) / bone.depth);
      strokeSegment(view, joints[bone.j], joints[bone.p]);
    }

    // Joints as dots, the head as a larger disc.
    for (let j = 0; j < joints.length; j++) {
      const c = cam[j];
      if (c[2] < NEAR) continue;
      const s = toScreen(view, c);
      const radius = ((j === state.headJoint ? 0.1 : 0.028) * view.focal) / c[2];
      ctx.beginPath();
      ctx.arc(s[0], s[1], Math.max(1.5 * dpr, radius), 0, 2 * Math.PI);
      ctx.fillStyle = j === state.headJoint ? '#e3e6eb' : '#0f1215';
      ctx.fill();
      ctx.lineWidth = Math.max(1, 0.012 * view.focal / c[2]);
      ctx.strokeStyle = SIDE_COLORS[state.sides[j]] || SIDE_COLORS.centre;
      ctx.stroke();
    }
  }

  function drawPlaceholder(w, h, dpr) {
    ctx.fillStyle = 'rgba(227, 230, 235, 0.55)';
    ctx.font = `${15 * dpr}px system-ui, sans-serif`;
    ctx.textAlign = 'center';
    ctx.fillText('Type sentences on the left and press Generate', w / 2, h * 0.42);
  }

  function render() {
    const dpr = resizeCanvas();
    const w = ui.canvas.width;
    const h = ui.canvas.height;
    const view = makeView(w, h);
    drawBackground(w, h);
    drawGrid(view, dpr);
    const motion = state.motion;
    if (!motion) {
      drawPlaceholder(w, h, dpr);
      return;
    }
    drawTrajectory(view, motion.frames, state.frame, dpr);
    drawSkeleton(view, motion.frames[state.frame], motion.parents, dpr);
  }

  // ---------------------------------------------------------------- playback

  function setFrame(frame) {
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

  function showSegmentAt(frame) {
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

  function setPlaying(playing) {
    state.playing = playing;
    ui.play.textContent = playing ? 'Pause' : 'Play';
    if (state.motion) state.clock = state.frame / state.motion.fps;
  }

  function followTarget(dt) {
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

  function tick(now) {
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
  function playbackFrame() {
    const motion = state.motion;
    const available = motion.frames.length;
    const frame = Math.floor(state.clock * motion.fps);
    if (!state.streaming) return frame % available;
    if (frame < available) return frame;
    state.clock = (available - 1) / motion.fps;
    return available - 1;
  }

  /** Starts playing a motion whose first frames have arrived (appendFrames adds the next, finishMotion the rest). */
  function beginMotion(motion, request) {
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

  function appendFrames(frames) {
    state.motion.frames.push(...frames);
    ui.slider.max = String(state.motion.frames.length - 1);
    document.body.dataset.frames = String(state.motion.frames.length);
  }

  /** The stream's end message: the sentences' spans, the warnings; the motion now loops and can be downloaded. */
  function finishMotion(end) {
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
  function buildSegmentStrip(segments, total) {
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

  // ---------------------------------------------------------------- editing a segment (POST /edit)

  /** The edit kinds (GET /health `extra.edits`) of the model that made the motion shown. */
  function editKinds() {
    const name = state.motion && state.motion.model && state.motion.model.name;
    const model = state.models.find((m) => m.name === name);
    const kinds = model && model.extra && model.extra.edits;
    return Array.isArray(kinds) ? kinds : [];
  }

  /** Selects segment `index` of the motion shown (-1: none) and puts its text in the edit bar. */
  function selectSegment(index) {
    const segments = (state.motion && state.motion.segments) || [];
    state.selected = index >= 0 && index < segments.length ? index : -1;
    Array.from(ui.strip.children).forEach((el, i) => el.classList.toggle('selected', i === state.selected));
    ui.editText.value = state.selected >= 0 ? segments[state.selected].text : '';
    ui.editText.classList.remove('invalid');
    document.body.dataset.selected = String(state.selected);
    refreshEditPanel();
  }

  /** Enables what can be sent now: a selected segment of a whole motion with a handle, kinds the model supports. */
  function refreshEditPanel() {
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
  async function onEdit(reroll) {
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
  function showEdited(answer, index) {
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

  // ---------------------------------------------------------------- the form

  function addRow(text = '', duration = 3) {
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

  function readNumber(input) {
    const raw = input.value.trim();
    if (raw === '') return null;
    const value = Number(raw);
    return Number.isFinite(value) ? value : NaN;
  }

  /** The request body from the form; throws with the field named when something is plainly missing. */
  function buildRequest(format) {
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

  function fieldError(input, message) {
    input.classList.add('invalid');
    input.focus();
    return new Error(message);
  }

  function clearInvalid() {
    document.querySelectorAll('.invalid').forEach((el) => el.classList.remove('invalid'));
  }

  /** Marks the input a 422 error points at (loc like ["body", "segments", 1, "duration"]). */
  function markFromLocation(loc) {
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

  function showMessage(text, kind = '') {
    ui.message.textContent = text;
    ui.message.className = `message ${kind}`;
  }

  /** The model's warnings for the motion on screen (e.g. a sentence far from everything it was trained on). */
  function showWarnings(warnings) {
    ui.warnings.replaceChildren(...(warnings || []).map((text) => {
      const item = document.createElement('li');
      item.textContent = text;
      return item;
    }));
    ui.warnings.hidden = !(warnings && warnings.length);
  }

  /** A readable sentence for a failed response: names the fields (422), the wait (429), or the status. */
  async function describeFailure(response) {
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
  async function readMessages(response, onMessage) {
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
  async function playStream(response, body) {
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

  async function postJson(path, body) {
    const headers = { 'Content-Type': 'application/json' };
    const key = ui.apiKey.value.trim();
    if (key) headers.Authorization = `Bearer ${key}`;
    return fetch(path, { method: 'POST', headers, body: JSON.stringify(body) });
  }

  const postGenerate = (body) => postJson('generate', body);

  async function onGenerate(event) {
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

  function filenameFrom(response, fallback) {
    const disposition = response.headers.get('Content-Disposition') || '';
    const match = /filename\*?=(?:UTF-8'')?"?([^";]+)"?/i.exec(disposition);
    return match ? decodeURIComponent(match[1]) : fallback;
  }

  /** Asks for the shown motion again in another format (same request, same seed; an edited motion: its handle
   * with no edits, the same motion bit for bit) and saves the file. */
  async function download(format, button) {
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

  // ---------------------------------------------------------------- server status

  /** Fills the model choice from /health (kept when the list is unchanged); hidden when there is only one model. */
  function showModels(health) {
    const models = Array.isArray(health.models) ? health.models.filter((m) => m && m.name) : [];
    const names = models.map((m) => m.name);
    if (names.join('\n') !== state.models.map((m) => m.name).join('\n')) {
      const previous = ui.model.value;
      ui.model.replaceChildren(...models.map((m) => {
        const option = document.createElement('option');
        option.value = m.name;
        option.textContent = `${m.name} ${m.version || ''}${m.name === health.default ? ' (default)' : ''}`;
        return option;
      }));
      ui.model.value = names.includes(previous) ? previous : health.default || names[0] || '';
    }
    state.models = models;
    ui.modelField.hidden = models.length < 2;
    refreshEditPanel();
  }

  /** A newly chosen model brings its own guidance default (1 for a model without an unconditional branch). */
  function onModelChange() {
    const chosen = state.models.find((m) => m.name === ui.model.value);
    if (chosen) ui.guidance.value = String(chosen.unconditional_branch ? chosen.default_guidance : 1);
  }

  async function pollHealth() {
    let delay = 5000;
    try {
      const response = await fetch('health', { cache: 'no-store' });
      if (response.ok) {
        const health = await response.json().catch(() => ({}));
        const model = health.model || {};
        showModels(health);
        ui.serverStatus.textContent = state.models.length > 1 ? `${state.models.length} models · ready`
          : model.name ? `${model.name} ${model.version || ''} · ready` : 'model ready';
        ui.serverStatus.className = 'pill ready';
        delay = 30000;
      } else {
        ui.serverStatus.textContent = 'model loading…';
        ui.serverStatus.className = 'pill loading';
        delay = 2000;
      }
    } catch (_) {
      ui.serverStatus.textContent = 'server unreachable';
      ui.serverStatus.className = 'pill down';
    }
    setTimeout(pollHealth, delay);
  }

  // ---------------------------------------------------------------- camera controls

  ui.canvas.addEventListener('pointerdown', (e) => {
    state.drag = { x: e.clientX, y: e.clientY };
    ui.canvas.setPointerCapture(e.pointerId);
    ui.canvas.classList.add('dragging');
    ui.canvas.focus();
  });
  ui.canvas.addEventListener('pointermove', (e) => {
    if (!state.drag) return;
    const cam = state.camera;
    cam.yaw -= (e.clientX - state.drag.x) * 0.008;
    cam.pitch = clamp(cam.pitch + (e.clientY - state.drag.y) * 0.006, PITCH_LIMITS[0], PITCH_LIMITS[1]);
    state.drag = { x: e.clientX, y: e.clientY };
  });
  const endDrag = () => {
    state.drag = null;
    ui.canvas.classList.remove('dragging');
  };
  ui.canvas.addEventListener('pointerup', endDrag);
  ui.canvas.addEventListener('pointercancel', endDrag);
  ui.canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    const cam = state.camera;
    cam.distance = clamp(cam.distance * Math.exp(e.deltaY * 0.0012), DISTANCE_LIMITS[0], DISTANCE_LIMITS[1]);
  }, { passive: false });
  ui.canvas.addEventListener('keydown', (e) => {
    if (!state.motion) return;
    if (e.key === ' ') {
      e.preventDefault();
      setPlaying(!state.playing);
    } else if (e.key === 'ArrowRight' || e.key === 'ArrowLeft') {
      e.preventDefault();
      setPlaying(false);
      setFrame(state.frame + (e.key === 'ArrowRight' ? 1 : -1));
      state.clock = state.frame / state.motion.fps;
    }
  });

  // ---------------------------------------------------------------- wiring

  ui.form.addEventListener('submit', onGenerate);
  ui.addRow.addEventListener('click', () => addRow('', 3).querySelector('.seg-text').focus());
  ui.play.addEventListener('click', () => setPlaying(!state.playing));
  ui.slider.addEventListener('input', () => {
    setFrame(Number(ui.slider.value));
    if (state.motion) state.clock = state.frame / state.motion.fps;
  });
  ui.downloadBvh.addEventListener('click', () => download('bvh', ui.downloadBvh));
  ui.downloadGlb.addEventListener('click', () => download('glb', ui.downloadGlb));
  ui.form.addEventListener('input', (e) => e.target.classList.remove('invalid'));
  ui.model.addEventListener('change', onModelChange);
  ui.editRegenerate.addEventListener('click', () => onEdit(false));
  ui.editReroll.addEventListener('click', () => onEdit(true));
  ui.editUpper.addEventListener('change', refreshEditPanel);
  ui.editText.addEventListener('input', () => ui.editText.classList.remove('invalid'));
  ui.editText.addEventListener('keydown', (e) => {
    if (e.key === 'Enter') {
      e.preventDefault();
      onEdit(false);
    }
  });

  DEFAULT_ROWS.forEach(([text, duration]) => addRow(text, duration));
  pollHealth();
  window.requestAnimationFrame(tick);
})();
