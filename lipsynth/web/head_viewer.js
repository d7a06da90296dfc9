// The animated 3D head (a lipsynth .glb) in a page: three.js (vendored, lipsynth/web/three/), orbit controls,
// the animation driven by the <audio> element's clock so picture and sound stay together.
//
// Works from file:// (a report folder opened from disk): module scripts cannot be fetched there, so the
// vendored modules arrive as text in a classic script (window.LIPSYNTH_THREE_MODULES, written by
// pipeline/face/gltf_viewer.py) and are imported from blob: URLs; the .glb arrives base64-encoded in a
// classic script too (window.LIPSYNTH_GLB[name]).
//
// Markup: <div class="lipsynth-head" data-glb="NAME"><canvas></canvas><audio controls src="..."></audio></div>
// Each such div gets a viewer; window.lipsynthViewers[i] exposes {ready, shownTime, frameTime, fps, audio,
// vertexAt(t, i), snapshot()} for tests.
(function () {
  "use strict";
  const ORDER = ["three.core.js", "three.module.js", "BufferGeometryUtils.js", "SkeletonUtils.js",
                 "GLTFLoader.js", "OrbitControls.js"];

  function loadModules() {          // blob: URL per vendored module, its imports rewritten to the others' URLs
    const src = window.LIPSYNTH_THREE_MODULES, url = {};
    const alias = {"three": "three.module.js", "./three.core.js": "three.core.js",
                   "../utils/BufferGeometryUtils.js": "BufferGeometryUtils.js",
                   "../utils/SkeletonUtils.js": "SkeletonUtils.js"};
    for (const name of ORDER) {
      const code = src[name].replace(/(from\s*)(['"])([^'"]+)\2/g,
        (m, pre, q, spec) => (alias[spec] && url[alias[spec]]) ? pre + q + url[alias[spec]] + q : m);
      url[name] = URL.createObjectURL(new Blob([code], {type: "text/javascript"}));
    }
    return Promise.all([import(url["three.module.js"]), import(url["GLTFLoader.js"]),
                        import(url["OrbitControls.js"])]);
  }

  function glbBytes(name) {
    const b64 = window.LIPSYNTH_GLB[name], bin = atob(b64), out = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out.buffer;
  }

  async function viewer(div, [THREE, {GLTFLoader}, {OrbitControls}]) {
    const canvas = div.querySelector("canvas");
    const audio = div.querySelector("audio") || {currentTime: 0, play: () => Promise.resolve()};   // no audio: frame 0
    const state = {ready: false, shownTime: 0, frameTime: 0, fps: 25, audio: audio, frames: 0};
    const renderer = new THREE.WebGLRenderer({canvas, antialias: true, preserveDrawingBuffer: true});
    renderer.setPixelRatio(1);
    renderer.setSize(canvas.width, canvas.height, false);
    renderer.outputColorSpace = THREE.SRGBColorSpace;
    const scene = new THREE.Scene();
    scene.background = new THREE.Color(0x202020);
    scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 1.6));
    const key = new THREE.DirectionalLight(0xffffff, 1.8);
    key.position.set(0.25, 0.3, 0.6);
    scene.add(key);
    const gltf = await new Promise((ok, fail) => new GLTFLoader().parse(glbBytes(div.dataset.glb), "", ok, fail));
    scene.add(gltf.scene);
    const extras = gltf.scene.userData || {};
    state.fps = extras.fps || 25;
    const box = new THREE.Box3().setFromObject(gltf.scene), size = box.getSize(new THREE.Vector3());
    const centre = box.getCenter(new THREE.Vector3());
    const camera = new THREE.PerspectiveCamera(22, canvas.width / canvas.height, 0.01, 10);
    camera.position.set(centre.x, centre.y, centre.z + 3.0 * size.y);
    const controls = new OrbitControls(camera, canvas);
    controls.target.copy(centre);
    controls.update();
    const mixer = new THREE.AnimationMixer(gltf.scene);
    const clip = gltf.animations[0], action = mixer.clipAction(clip);
    action.play();
    const head = gltf.scene.getObjectByName("head");
    const skin = head.isMesh ? head : head.children.find(c => c.isMesh);

    function draw() {
      const t = Math.min(audio.currentTime, clip.duration);
      mixer.setTime(t);               // the audio element's clock drives the animation
      controls.update();
      renderer.render(scene, camera);
      state.shownTime = t;
      state.frameTime = Math.round(t * state.fps) / state.fps;
      state.frames += 1;
    }
    renderer.setAnimationLoop(draw);
    state.vertexAt = (t, i) => {      // skin vertex i (glTF metres) with the morphs at animation time t
      mixer.setTime(t);
      const v = skin.getVertexPosition(i, new THREE.Vector3());
      mixer.setTime(Math.min(audio.currentTime, clip.duration));
      return [v.x, v.y, v.z];
    };
    state.snapshot = () => {          // the canvas shrunk to 64 × 64 RGBA (for "is it drawn, does it move")
      const c = document.createElement("canvas");
      c.width = c.height = 64;
      const g = c.getContext("2d");
      g.drawImage(canvas, 0, 0, 64, 64);
      return Array.from(g.getImageData(0, 0, 64, 64).data);
    };
    state.duration = clip.duration;
    state.ready = true;
    return state;
  }

  window.lipsynthViewers = [];
  window.lipsynthViewerError = null;
  const divs = [...document.querySelectorAll("div.lipsynth-head")];
  if (divs.length) {
    loadModules().then(mods => Promise.all(divs.map(async (d, i) => {
      window.lipsynthViewers[i] = {ready: false};
      window.lipsynthViewers[i] = await viewer(d, mods);
    }))).catch(e => { window.lipsynthViewerError = String(e); console.error(e); });
  }
})();
