/** The pinhole camera orbiting a target: world -> camera -> canvas, clipped at the near plane. */
import { FIELD_OF_VIEW, NEAR, ctx, state, sub, add, scale, dot, cross, normalize } from './state.js';

/** The camera basis for this frame: eye on a sphere around the target, looking at it, Y up. */
export function makeView(width, height) {
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
export function toCamera(view, p) {
  const d = sub(p, view.eye);
  return [dot(d, view.right), dot(d, view.up), dot(d, view.forward)];
}

/** Camera coordinates -> canvas pixels (only for depth >= NEAR). */
export function toScreen(view, c) {
  return [view.cx + (view.focal * c[0]) / c[2], view.cy - (view.focal * c[1]) / c[2]];
}

/** Clips a camera-space segment against the near plane; null when it lies wholly behind it. */
export function clipNear(a, b) {
  if (a[2] < NEAR && b[2] < NEAR) return null;
  if (a[2] >= NEAR && b[2] >= NEAR) return [a, b];
  const t = (NEAR - a[2]) / (b[2] - a[2]);
  const hit = [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, NEAR];
  return a[2] < NEAR ? [hit, b] : [a, hit];
}

export function strokeSegment(view, a, b) {
  const clipped = clipNear(toCamera(view, a), toCamera(view, b));
  if (!clipped) return;
  const p = toScreen(view, clipped[0]);
  const q = toScreen(view, clipped[1]);
  ctx.beginPath();
  ctx.moveTo(p[0], p[1]);
  ctx.lineTo(q[0], q[1]);
  ctx.stroke();
}
