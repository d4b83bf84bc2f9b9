/** What every part of the viewer shares: the constants, the page's elements, the one state object, vector helpers. */
import { addRow, download } from './form.js';

export const FIELD_OF_VIEW = (50 * Math.PI) / 180; // vertical
export const NEAR = 0.05; // metres; lines are clipped here so nothing behind the camera is drawn
export const GRID_HALF = 8; // metres of floor grid on each side of the camera target
export const PITCH_LIMITS = [0.03, 1.45];
export const DISTANCE_LIMITS = [1.2, 30];
export const SEGMENT_COLORS = ['#4fa3ff', '#f5a35c', '#6fd49a', '#e07bd4', '#f0d35a', '#7fd6e0', '#ff8a8a', '#b39ddb'];
export const SIDE_COLORS = { left: '#4fa3ff', right: '#f5a35c', centre: '#e3e6eb' };
export const DEFAULT_ROWS = [
  ['a person walks forward', 3],
  ['a person turns around and waves', 3],
];


export const $ = (id) => document.getElementById(id);
export const ui = {
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
export const ctx = ui.canvas.getContext('2d');

export const state = {
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


export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const normalize = (a) => scale(a, 1 / Math.hypot(a[0], a[1], a[2]));
export const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));
