/** One frame on the canvas: background, floor grid, the pelvis path, the skeleton. */
import { NEAR, GRID_HALF, SIDE_COLORS, $, ui, ctx, state } from './state.js';
import { makeView, toCamera, toScreen, strokeSegment } from './camera.js';

export function resizeCanvas() {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(ui.canvas.clientWidth * dpr));
  const h = Math.max(1, Math.round(ui.canvas.clientHeight * dpr));
  if (ui.canvas.width !== w || ui.canvas.height !== h) {
    ui.canvas.width = w;
    ui.canvas.height = h;
  }
  return dpr;
}

export function drawBackground(w, h) {
  const sky = ctx.createLinearGradient(0, 0, 0, h);
  sky.addColorStop(0, '#1d232c');
  sky.addColorStop(1, '#0f1215');
  ctx.fillStyle = sky;
  ctx.fillRect(0, 0, w, h);
}

/** A 1 m floor grid around the target, fading with distance so its edge does not show. */
export function drawGrid(view, dpr) {
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
export function drawTrajectory(view, frames, upTo, dpr) {
  ctx.lineWidth = 2 * dpr;
  for (let f = 1; f < frames.length; f++) {
    const a = frames[f - 1][0];
    const b = frames[f][0];
    ctx.strokeStyle = f <= upTo ? 'rgba(79, 163, 255, 0.55)' : 'rgba(79, 163, 255, 0.16)';
    strokeSegment(view, [a[0], 0.002, a[2]], [b[0], 0.002, b[2]]);
  }
}

export function drawSkeleton(view, joints, parents, dpr) {
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

export function drawPlaceholder(w, h, dpr) {
  ctx.fillStyle = 'rgba(227, 230, 235, 0.55)';
  ctx.font = `${15 * dpr}px system-ui, sans-serif`;
  ctx.textAlign = 'center';
  ctx.fillText('Type sentences on the left and press Generate', w / 2, h * 0.42);
}

export function render() {
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
