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

import { wireCameraControls } from './controls.js';
import { DEFAULT_ROWS, ui, state } from './state.js';
import { setFrame, setPlaying, tick } from './playback.js';
import { refreshEditPanel, onEdit } from './editing.js';
import { addRow, onGenerate, download } from './form.js';
import { onModelChange, pollHealth } from './status.js';

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

wireCameraControls();
DEFAULT_ROWS.forEach(([text, duration]) => addRow(text, duration));
pollHealth();
window.requestAnimationFrame(tick);
