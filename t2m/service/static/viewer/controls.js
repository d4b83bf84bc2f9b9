/** Orbit, zoom and keyboard controls of the camera. */
import { PITCH_LIMITS, DISTANCE_LIMITS, ui, state, clamp } from './state.js';
import { setFrame, setPlaying } from './playback.js';

/** Registers the canvas's pointer, wheel and keyboard handlers. */
export function wireCameraControls() {

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

}
