/** The server's status and its models (GET /health). */
import { $, ui, state } from './state.js';
import { refreshEditPanel } from './editing.js';

/** Fills the model choice from /health (kept when the list is unchanged); hidden when there is only one model. */
export function showModels(health) {
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
export function onModelChange() {
  const chosen = state.models.find((m) => m.name === ui.model.value);
  if (chosen) ui.guidance.value = String(chosen.unconditional_branch ? chosen.default_guidance : 1);
}

export async function pollHealth() {
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
