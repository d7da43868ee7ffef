// The dashboard in a real browser: headless Chromium (the system's, /usr/bin/chromium, driven by
// playwright-core) against a `lightfarm serve` process in team mode. Checks that the page lists
// a bake submitted through the API and shows it progress to succeeded, that the 3D preview
// draws the level (pixels that are not the background; lit and indirect-only views differ),
// that cancel works, and that a team's token hides the other team's bakes. Prints the page's
// load time and the bytes the browser downloaded, with the maze preview's size and time.
//
// Usage: node dashboard.test.mjs [path/to/lightfarm]   (default: ../../target/release/lightfarm)
// SCREENSHOTS=DIR keeps the screenshots (docs/ in the repository holds the README's);
// CHROMIUM=PATH picks another browser binary.

import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import readline from 'node:readline';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = path.dirname(fileURLToPath(import.meta.url));
const root = path.resolve(here, '../..');
const binary = process.argv[2] || path.join(root, 'target/release/lightfarm');
const browserPath = process.env.CHROMIUM || '/usr/bin/chromium';
const shots = process.env.SCREENSHOTS || fs.mkdtempSync(path.join(os.tmpdir(), 'lightfarm-shots-'));
const work = fs.mkdtempSync(path.join(os.tmpdir(), 'lightfarm-browser-'));

if (!fs.existsSync(browserPath)) {
  console.log(`SKIP: no browser at ${browserPath} (apt-get install chromium)`);
  process.exit(0);
}

const config = path.join(work, 'config.toml');
fs.writeFileSync(config, `[[teams]]
name = "red"
token = "red-token"
[[teams]]
name = "blue"
token = "blue-token"
`);

// The server, on a free loopback port.
const server = spawn(binary, ['serve', '--addr', '127.0.0.1:0', '--data', path.join(work, 'data'), '--config', config],
  { stdio: ['ignore', 'pipe', 'inherit'] });
const base = await new Promise((resolve, reject) => {
  const lines = readline.createInterface({ input: server.stdout });
  lines.on('line', (line) => {
    const m = line.match(/listening on (http:\/\/\S+)/);
    if (m) resolve(m[1]);
  });
  server.on('exit', (code) => reject(new Error(`server exited with ${code}`)));
});

async function api(tokenValue, method, route, body) {
  const response = await fetch(base + route, {
    method,
    headers: { Authorization: `Bearer ${tokenValue}`, 'content-type': 'application/json' },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await response.text();
  assert.ok(response.ok, `${method} ${route}: ${response.status} ${text}`);
  return JSON.parse(text);
}

const sceneText = (name) => JSON.parse(fs.readFileSync(path.join(root, 'scenes', name, 'scene.json'), 'utf8'));
const small = { texels_per_face: 6, rays_per_texel: 64 };
const maze = await api('red-token', 'POST', '/v1/scenes', sceneText('maze'));
const redBake = (await api('red-token', 'POST', '/v1/bakes', { scene: maze.id, settings: small })).id;
const cornell = await api('blue-token', 'POST', '/v1/scenes', sceneText('cornell'));
const blueBake = (await api('blue-token', 'POST', '/v1/bakes', { scene: cornell.id, settings: small })).id;

const context = await chromium.launchPersistentContext(path.join(work, 'profile'), {
  executablePath: browserPath,
  headless: true,
  viewport: { width: 1600, height: 1000 },
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
    '--disable-background-networking', '--disable-component-update', '--disable-sync',
    // WebGL without a GPU: ANGLE on SwiftShader.
    '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
});
const failures = [];
let page;
try {
  page = context.pages()[0] || await context.newPage();
  page.on('pageerror', (e) => failures.push(`page error: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error') console.log(`browser console: ${m.text()}`); });
  await page.addInitScript(() => { if (!localStorage.getItem('lightfarm.token')) localStorage.setItem('lightfarm.token', 'red-token'); });

  // 1. The bake submitted through the API is listed and progresses to succeeded.
  await page.goto(base + '/');
  const row = (id) => page.locator(`#bakes tr[data-id="${id}"]`);
  await row(redBake).waitFor({ timeout: 30000 });
  const load = await page.evaluate(() => {
    const nav = performance.getEntriesByType('navigation')[0];
    const resources = performance.getEntriesByType('resource');
    return {
      loadMs: nav.loadEventEnd - nav.startTime,
      bytes: nav.transferSize + resources.reduce((s, r) => s + r.transferSize, 0),
      files: 1 + resources.length,
    };
  });
  console.log(`dashboard page: load event after ${load.loadMs.toFixed(0)} ms, ${load.bytes} bytes transferred in ${load.files} files`);
  const states = new Set();
  const deadline = Date.now() + 600000;
  for (;;) {
    const state = (await row(redBake).locator('.state').textContent()).trim();
    states.add(state);
    if (state === 'succeeded') break;
    assert.ok(!['failed', 'cancelled'].includes(state), `bake ended ${state}`);
    assert.ok(Date.now() < deadline, 'bake did not finish in 10 min');
    await page.waitForTimeout(200);
  }
  console.log(`states seen in the table: ${[...states].join(' → ')}`);
  assert.equal(await row(blueBake).count(), 0, "red's page shows blue's bake");
  assert.match(await row(redBake).locator('.stages').textContent(), /\d+\.\d\d/, 'per-stage times shown');
  assert.match(await row(redBake).locator('.bundle').textContent(), /[kM]B/, 'bundle size shown');

  // 2. The 3D preview draws the level; lit and indirect-only differ.
  const loaded = async (previous) => {
    await page.waitForFunction((p) => {
      const v = document.querySelector('#view').dataset.loaded;
      return v && v !== p;
    }, previous, { timeout: 120000 });
    return page.locator('#view').getAttribute('data-loaded');
  };
  const previewStart = Date.now();
  await row(redBake).locator('button.preview').click();
  let mark = await loaded(undefined);
  await page.locator('#lights-file').setInputFiles(path.join(root, 'scenes/maze/lights.json'));
  const lightsStart = Date.now();
  mark = await loaded(mark);
  const previewSeconds = (Date.now() - lightsStart) / 1000;
  const pixels = () => page.evaluate(() => {
    const canvas = document.querySelector('#view canvas');
    const copy = document.createElement('canvas');
    copy.width = canvas.width;
    copy.height = canvas.height;
    const ctx = copy.getContext('2d');
    ctx.drawImage(canvas, 0, 0);
    const data = ctx.getImageData(0, 0, copy.width, copy.height).data;
    let level = 0;
    let sum = 0;
    for (let i = 0; i < data.length; i += 4) {
      const off = Math.abs(data[i] - 0x20) + Math.abs(data[i + 1] - 0x24) + Math.abs(data[i + 2] - 0x28);
      if (off > 12) { level += 1; sum += data[i] + data[i + 1] + data[i + 2]; }
    }
    window.lastPixels = data;
    return { level: level / (data.length / 4), mean: sum / Math.max(1, 3 * level) };
  });
  const lit = await pixels();
  await page.evaluate(() => { window.litPixels = window.lastPixels; });
  await page.locator('#view').screenshot({ path: path.join(shots, 'preview-lit.png') });
  await page.screenshot({ path: path.join(shots, 'dashboard.png') });
  const glb = await page.evaluate(() => performance.getEntriesByType('resource')
    .filter((r) => r.name.endsWith('preview.glb')).map((r) => ({ transfer: r.transferSize, body: r.decodedBodySize })).pop());
  console.log(`maze preview: ${glb.body} bytes of glTF (${glb.transfer} transferred), evaluated and drawn in ${previewSeconds.toFixed(2)} s (first view ${((lightsStart - previewStart) / 1000).toFixed(2)} s)`);
  console.log(`lit view: ${(100 * lit.level).toFixed(1)}% of pixels show the level, mean ${lit.mean.toFixed(1)}`);
  assert.ok(lit.level > 0.05, `the view is background only (${lit.level})`);

  await page.locator('input[name=light][value=indirect]').check();
  mark = await loaded(mark);
  assert.ok(mark.startsWith('indirect-'), mark);
  const indirect = await pixels();
  const changed = await page.evaluate(() => {
    const a = window.litPixels;
    const b = window.lastPixels;
    let n = 0;
    for (let i = 0; i < a.length; i += 4) {
      if (Math.abs(a[i] - b[i]) + Math.abs(a[i + 1] - b[i + 1]) + Math.abs(a[i + 2] - b[i + 2]) > 24) n += 1;
    }
    return n / (a.length / 4);
  });
  await page.locator('#view').screenshot({ path: path.join(shots, 'preview-indirect.png') });
  console.log(`indirect view: ${(100 * indirect.level).toFixed(1)}% level pixels, mean ${indirect.mean.toFixed(1)}; ${(100 * changed).toFixed(1)}% of pixels differ from the lit view`);
  assert.ok(indirect.level > 0.05, 'indirect view is background only');
  assert.ok(changed > 0.05, `lit and indirect views barely differ (${changed})`);

  // 3. Cancel: a long bake is cancelled from its row.
  const long = (await api('red-token', 'POST', '/v1/bakes', { scene: maze.id, settings: { texels_per_face: 16, rays_per_texel: 4096 } })).id;
  await page.locator('#refresh').click();
  await row(long).locator('button.cancel').click({ timeout: 30000 });
  await page.waitForFunction((id) => document.querySelector(`#bakes tr[data-id="${id}"] .state`)?.textContent === 'cancelled',
    long, { timeout: 60000 });
  const status = await api('red-token', 'GET', `/v1/bakes/${long}`);
  assert.equal(status.state, 'cancelled');
  console.log('cancel: the long bake is cancelled');

  // 4. Blue's token shows blue's bake and none of red's.
  await page.locator('#token').fill('blue-token');
  await page.locator('#token').dispatchEvent('change');
  await row(blueBake).waitFor({ timeout: 30000 });
  assert.equal(await row(redBake).count(), 0, "blue's page shows red's bake");
  assert.equal(await row(long).count(), 0, "blue's page shows red's cancelled bake");
  console.log("team token: blue sees its bake and none of red's");
  assert.deepEqual(failures, []);
  console.log(`PASS (screenshots in ${shots})`);
} catch (e) {
  if (page) await page.screenshot({ path: path.join(shots, 'failure.png') }).catch(() => {});
  console.error(`FAIL: ${e.stack || e} (screenshot ${path.join(shots, 'failure.png')})`);
  process.exitCode = 1;
} finally {
  await context.close();
  server.kill('SIGTERM');
  fs.rmSync(work, { recursive: true, force: true });
}
