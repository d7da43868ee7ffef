// The dashboard: the team's bakes with live progress (server-sent events), cancel, scene
// submission (files or drag and drop), and the 3D preview of a finished bake (preview.js).

import { token, setToken, request, json, followEvents } from './api.js';
import { Preview } from './preview.js';

const $ = (selector) => document.querySelector(selector);
const bakes = new Map(); // id -> { status, sections, row, follow: AbortController }
const sceneNames = new Map(); // scene id -> name
let nextPage = null;
let preview = null;

function say(text) { $('#status').textContent = text; }

function short(id) { return id ? id.slice(0, 10) : ''; }

function bytes(n) {
  if (n == null) return '';
  return n > 1e6 ? `${(n / 1e6).toFixed(2)} MB` : `${(n / 1e3).toFixed(1)} kB`;
}

function render(entry) {
  const s = entry.status;
  let row = entry.row;
  if (!row) {
    row = document.createElement('tr');
    row.dataset.id = s.id;
    row.innerHTML = '<td class="id"></td><td class="scene"></td><td class="state"></td>'
      + '<td class="progress"><progress max="1"></progress> <span class="stage"></span></td>'
      + '<td class="stages"></td><td class="bundle"></td><td class="actions"></td>';
    entry.row = row;
  }
  row.querySelector('.id').textContent = short(s.id);
  row.querySelector('.id').title = s.id;
  row.querySelector('.scene').textContent = sceneNames.get(s.scene) || short(s.scene);
  const state = row.querySelector('.state');
  state.textContent = s.state;
  state.className = `state state-${s.state}`;
  row.querySelector('progress').value = s.state === 'succeeded' ? 1 : s.progress;
  row.querySelector('.stage').textContent = s.state === 'running' && s.stage
    ? `${s.stage} ${s.stage_done}/${s.stage_total}` : '';
  row.querySelector('.stages').textContent = s.stages
    .map((t) => `${t.stage} ${t.seconds.toFixed(2)}`).join(' · ');
  const sections = entry.sections ? ` (${entry.sections.join(', ')})` : '';
  row.querySelector('.bundle').textContent = s.bundle_bytes != null
    ? `${bytes(s.bundle_bytes)}${sections}` : sections;
  const actions = row.querySelector('.actions');
  actions.replaceChildren();
  if (s.state === 'queued' || s.state === 'running') {
    const cancel = document.createElement('button');
    cancel.textContent = 'Cancel';
    cancel.className = 'cancel';
    cancel.onclick = async () => {
      try { update(await json('DELETE', `/v1/bakes/${s.id}`)); } catch (e) { say(e.message); }
    };
    actions.append(cancel);
  }
  if (s.state === 'succeeded') {
    const show = document.createElement('button');
    show.textContent = 'Preview';
    show.className = 'preview';
    show.onclick = () => openPreview(s);
    actions.append(show);
  }
  return row;
}

function update(status) {
  const entry = bakes.get(status.id) || { status };
  entry.status = status;
  bakes.set(status.id, entry);
  render(entry);
  if (!status.state || ['queued', 'running'].includes(status.state)) follow(entry);
}

// Live progress of a queued or running bake from its event stream.
function follow(entry) {
  if (entry.follow) return;
  entry.follow = new AbortController();
  const id = entry.status.id;
  followEvents(id, (kind, event) => {
    const s = entry.status;
    if (kind === 'state') {
      s.state = event.state;
      s.error = event.error;
      if (event.bundle) s.bundle = event.bundle;
    } else if (kind === 'stage') {
      s.stage = event.stage;
      s.stage_done = 0;
      s.stage_total = event.total;
    } else if (kind === 'progress') {
      s.stage = event.stage;
      s.stage_done = event.done;
      s.stage_total = event.total;
      s.progress = event.overall;
    } else if (kind === 'sections') {
      entry.sections = event.sections;
    }
    render(entry);
  }, entry.follow.signal).catch(() => {}).finally(async () => {
    entry.follow = null;
    // The stream ends after a final state: read the record for timings and bundle size.
    try { entry.status = await json('GET', `/v1/bakes/${id}`); render(entry); } catch (_) { /* gone */ }
  });
}

async function loadScenes() {
  try {
    const page = await json('GET', '/v1/scenes?limit=200');
    for (const s of page.scenes) sceneNames.set(s.id, s.name);
  } catch (_) { /* the bakes table still works */ }
}

async function loadBakes(more = false) {
  const state = $('#state-filter').value;
  const path = more && nextPage ? nextPage
    : `/v1/bakes?limit=20${state ? `&state=${state}` : ''}`;
  try {
    const page = await json('GET', path);
    const body = $('#bakes tbody');
    if (!more) {
      const listed = new Set(page.bakes.map((b) => b.id));
      for (const [id, entry] of bakes) {
        if (!listed.has(id)) { entry.follow?.abort(); bakes.delete(id); }
      }
      body.replaceChildren();
    }
    await loadScenes();
    for (const status of page.bakes) {
      // A bake followed live keeps the state its events gave it.
      if (!bakes.get(status.id)?.follow) update(status);
      body.append(bakes.get(status.id).row);
    }
    nextPage = page.next;
    $('#more').hidden = !nextPage;
    say(`${bakes.size} bake${bakes.size === 1 ? '' : 's'}`);
  } catch (e) {
    say(e.message);
  }
}

// Submission: meshes first (their hashes replace the file names in the scene), then the
// scene, then the bake.
async function submit(files) {
  const out = $('#submit-result');
  const sceneFile = files.find((f) => f.name.endsWith('.json'));
  if (!sceneFile) { out.textContent = 'no scene .json among the files'; return; }
  try {
    const scene = JSON.parse(await sceneFile.text());
    const hashes = new Map();
    for (const f of files.filter((f) => f !== sceneFile)) {
      const created = await (await request('POST', '/v1/assets', f, 'application/octet-stream')).json();
      hashes.set(f.name, created.hash);
    }
    for (const list of [scene.clutter || [], scene.dynamic || []]) {
      for (const object of list) {
        const name = typeof object.mesh === 'string' ? object.mesh.split('/').pop() : null;
        if (name && hashes.has(name)) object.mesh = hashes.get(name);
      }
    }
    const created = await json('POST', '/v1/scenes', scene);
    sceneNames.set(created.id, created.name);
    const settings = {};
    if ($('#rays').value) settings.rays_per_texel = Number($('#rays').value);
    if ($('#texels').value) settings.texels_per_face = Number($('#texels').value);
    const status = await json('POST', '/v1/bakes', { scene: created.id, settings });
    out.textContent = `bake ${short(status.id)}: ${status.state}`;
    update(status);
    $('#bakes tbody').prepend(bakes.get(status.id).row);
  } catch (e) {
    out.textContent = e.message;
  }
}

function openPreview(status) {
  $('#preview-panel').hidden = false;
  $('#preview-title').textContent = `${sceneNames.get(status.scene) || ''} ${short(status.id)}`;
  if (!preview) preview = new Preview($('#view'), (text) => { $('#preview-status').textContent = text; });
  preview.open(status.id);
}

function init() {
  $('#token').value = token();
  $('#token').addEventListener('change', () => { setToken($('#token').value.trim()); loadBakes(); });
  $('#refresh').onclick = () => loadBakes();
  $('#more').onclick = () => loadBakes(true);
  $('#state-filter').onchange = () => loadBakes();
  $('#submit').addEventListener('submit', (e) => { e.preventDefault(); submit([...$('#files').files]); });
  const drop = $('#drop');
  drop.addEventListener('dragover', (e) => { e.preventDefault(); drop.classList.add('over'); });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (e) => {
    e.preventDefault();
    drop.classList.remove('over');
    submit([...e.dataTransfer.files]);
  });
  loadBakes();
  // New bakes submitted elsewhere (curl, an editor plugin) show up within a few seconds.
  setInterval(() => { if (!document.hidden) loadBakes(); }, 5000);
}

init();
