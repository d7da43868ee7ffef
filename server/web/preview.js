// The 3D preview of a finished bake: the server evaluates the bundle under the edited light set
// and answers with binary glTF (POST /v1/bakes/{id}/preview.glb); three.js draws it with an
// orbit camera. Lit / direct / indirect and one / all bounces re-request with the same lights.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { request } from './api.js';

const $ = (selector) => document.querySelector(selector);

export class Preview {
  constructor(container, say) {
    this.say = say;
    this.container = container;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    container.append(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x202428);
    this.camera = new THREE.PerspectiveCamera(50, 1, 0.05, 1000);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.draw());
    this.level = null;
    this.lights = [];
    this.framed = false;
    new ResizeObserver(() => this.resize()).observe(container);
    for (const input of document.querySelectorAll('input[name=light], input[name=bounces]')) {
      input.addEventListener('change', () => this.reload());
    }
    $('#relight').onclick = () => { this.readLightTable(); this.reload(); };
    $('#add-light').onclick = () => {
      this.readLightTable();
      const c = this.centre || [0, 1, 0];
      this.lights.push({ kind: 'point', position: [...c], intensity: [10, 10, 10] });
      this.writeLightTable();
    };
    $('#lights-file').addEventListener('change', async (e) => {
      const file = e.target.files[0];
      if (!file) return;
      this.lights = JSON.parse(await file.text()).lights || [];
      this.writeLightTable();
      this.reload();
    });
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.container;
    if (!w || !h) return;
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.draw();
  }

  draw() { this.renderer.render(this.scene, this.camera); }

  async open(id) {
    this.id = id;
    this.framed = false;
    this.centre = null;
    await this.reload();
  }

  options() {
    return {
      light: document.querySelector('input[name=light]:checked').value,
      bounces: document.querySelector('input[name=bounces]:checked').value,
    };
  }

  // Fetches the level lit by the current lights and shows it. Without lights yet, one light
  // goes to the centre of the level's bounds, two thirds up.
  async reload() {
    if (!this.id) return;
    const started = performance.now();
    this.say('evaluating…');
    try {
      let gltf = await this.fetchLevel();
      if (!this.lights.length) {
        const box = new THREE.Box3().setFromObject(gltf.scene);
        const c = box.getCenter(new THREE.Vector3());
        this.centre = [c.x, box.min.y + (box.max.y - box.min.y) * 0.66, c.z];
        this.lights = [{ kind: 'point', position: [...this.centre], intensity: [20, 20, 20] }];
        this.writeLightTable();
        gltf = await this.fetchLevel();
      }
      this.show(gltf);
      const { light, bounces } = this.options();
      this.say(`${light}, ${bounces} bounces: ${this.glbBytes} bytes in ${((performance.now() - started) / 1000).toFixed(2)} s`);
      this.container.dataset.loaded = `${light}-${bounces}-${Date.now()}`;
    } catch (e) {
      this.say(e.message);
    }
  }

  async fetchLevel() {
    const body = JSON.stringify({ lights: { lights: this.lights, poses: [] }, ...this.options() });
    const response = await request('POST', `/v1/bakes/${this.id}/preview.glb`, body, 'application/json');
    const buffer = await response.arrayBuffer();
    this.glbBytes = buffer.byteLength;
    const link = $('#download');
    if (link.href) URL.revokeObjectURL(link.href);
    link.href = URL.createObjectURL(new Blob([buffer], { type: 'model/gltf-binary' }));
    return new GLTFLoader().parseAsync(buffer, '');
  }

  show(gltf) {
    if (this.level) {
      this.scene.remove(this.level);
      this.level.traverse((o) => {
        o.geometry?.dispose();
        o.material?.map?.dispose();
        o.material?.dispose();
      });
    }
    this.level = gltf.scene;
    // The lights are baked into the textures; show where they are as small markers.
    for (const [k, l] of this.lights.entries()) {
      const marker = new THREE.Mesh(
        new THREE.SphereGeometry(0.08, 12, 8),
        new THREE.MeshBasicMaterial({ color: 0xffee88 }),
      );
      marker.position.set(...l.position);
      marker.name = `light marker ${k}`;
      this.level.add(marker);
    }
    this.scene.add(this.level);
    if (!this.framed) {
      const box = new THREE.Box3().setFromObject(this.level);
      const size = box.getSize(new THREE.Vector3()).length();
      const centre = box.getCenter(new THREE.Vector3());
      this.controls.target.copy(centre);
      // From above and to the side: the ceilings face inwards, so the camera sees into the rooms.
      this.camera.position.copy(centre).add(new THREE.Vector3(0.35, 0.9, 0.55).multiplyScalar(size * 1.05));
      this.camera.near = size / 1000;
      this.camera.far = size * 10;
      this.camera.updateProjectionMatrix();
      this.controls.update();
      this.framed = true;
    }
    this.resize();
    this.draw();
  }

  writeLightTable() {
    const body = $('#lights tbody');
    body.replaceChildren();
    for (const [k, l] of this.lights.entries()) {
      const row = document.createElement('tr');
      const cells = [...l.position, ...l.intensity]
        .map((v) => `<td><input type="number" step="0.1" value="${Number(v)}"></td>`).join('');
      row.innerHTML = `<td>${k}</td>${cells}<td><button type="button">×</button></td>`;
      row.querySelector('button').onclick = () => {
        this.readLightTable();
        this.lights.splice(k, 1);
        this.writeLightTable();
      };
      body.append(row);
    }
  }

  readLightTable() {
    this.lights = [...document.querySelectorAll('#lights tbody tr')].map((row) => {
      const v = [...row.querySelectorAll('input')].map((i) => Number(i.value));
      return { kind: 'point', position: v.slice(0, 3), intensity: v.slice(3, 6) };
    });
  }
}
