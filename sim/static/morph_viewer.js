/* morphshell morph viewer: the simulated shell in 3D, a time slider, colour modes and
 * picking.  One copy, used by the HTML report (inlined) and by `morphshell studio`.
 * Needs three.js as the global THREE (sim/static/three.min.js, MIT).  No network.
 *
 *   var v = new MorphViewer(element, data, {onPick: fn, ghost: true});   // data: sim/viewer.py
 *   v.setFrame(k); v.setTime(t); v.play(); v.pause(); v.setColorMode("completion");
 *   v.setGhost(on)   (the target surface, translucent, where the aligned frames should end)
 *   v.getView() / v.setView(view)  (camera)
 *   v.setScale("morph" | "frame" | "robust" | "fixed", [lo, hi])   the colour range
 *   v.preset("top" | "side" | "reset")   view presets
 *   MorphViewer.link([v1, v2])   one camera, one time slider and one colour scale
 *   MorphViewer.partView(element, stlArrayBuffer, {width, height})   an STL in 3D
 */
(function (global) {
  "use strict";

  function bytes(b64) {
    var s = atob(b64), n = s.length, u = new Uint8Array(n);
    for (var i = 0; i < n; i++) u[i] = s.charCodeAt(i);
    return u.buffer;
  }
  function f32(b64) { return new Float32Array(bytes(b64)); }
  function u32(b64) { return new Uint32Array(bytes(b64)); }
  // positions: {enc: "f32", data} or {enc: "u16", lo, span, data} -> Float32Array (mm)
  function positions(p) {
    if (p.enc === "f32") return f32(p.data);
    var q = new Uint16Array(bytes(p.data)), out = new Float32Array(q.length);
    for (var i = 0; i < q.length; i++) {
      var k = i % 3;
      out[i] = p.lo[k] + (q[i] / 65535) * p.span[k];
    }
    return out;
  }

  // colour maps: viridis (sequential) and blue-white-red (diverging), piecewise linear
  var VIRIDIS = [[0.267, 0.005, 0.329], [0.283, 0.141, 0.458], [0.254, 0.265, 0.530],
    [0.207, 0.372, 0.553], [0.164, 0.471, 0.558], [0.128, 0.567, 0.551],
    [0.135, 0.659, 0.518], [0.267, 0.749, 0.441], [0.478, 0.821, 0.318],
    [0.741, 0.873, 0.150], [0.993, 0.906, 0.144]];
  var DIVERGING = [[0.230, 0.299, 0.754], [0.865, 0.865, 0.865], [0.706, 0.016, 0.150]];
  function cmap(stops, x) {
    if (!(x >= 0)) x = 0;
    if (x > 1) x = 1;
    var f = x * (stops.length - 1), i = Math.min(Math.floor(f), stops.length - 2), u = f - i;
    var a = stops[i], b = stops[i + 1];
    return [a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1]), a[2] + u * (b[2] - a[2])];
  }
  function css(c) {
    return "rgb(" + Math.round(255 * c[0]) + "," + Math.round(255 * c[1]) + "," +
      Math.round(255 * c[2]) + ")";
  }
  function finite(v) { return v !== null && v !== undefined && isFinite(v); }
  function range(values) {
    var lo = Infinity, hi = -Infinity;
    for (var i = 0; i < values.length; i++) {
      var v = values[i];
      if (finite(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
    }
    if (!(lo <= hi)) { lo = 0; hi = 1; }
    if (hi - lo < 1e-9) hi = lo + 1;
    return [lo, hi];
  }
  // the p-th percentile (0-100) of the finite values, linear between order statistics
  function percentile(sorted, p) {
    if (!sorted.length) return NaN;
    var f = (sorted.length - 1) * p / 100, i = Math.floor(f), u = f - i;
    return i + 1 < sorted.length ? sorted[i] + u * (sorted[i + 1] - sorted[i]) : sorted[i];
  }
  // [lo, hi] of the values: all of them, or the 2nd-98th percentiles (robust: one outlier
  // does not stretch the scale; the values beyond are marked, see OUTLIER)
  function rangeOf(values, robust) {
    if (!robust) return range(values);
    var v = [];
    for (var i = 0; i < values.length; i++) if (finite(values[i])) v.push(values[i]);
    v.sort(function (a, b) { return a - b; });
    return range([percentile(v, ROBUST[0]), percentile(v, ROBUST[1])]);
  }
  var ROBUST = [2, 98];
  var OUTLIER = [1.0, 0.5, 0.0];   // orange: a value beyond the colour range
  function el(tag, attrs, parent) {
    var e = document.createElement(tag);
    for (var k in attrs || {}) {
      if (k === "text") e.textContent = attrs[k];
      else e.setAttribute(k, attrs[k]);
    }
    if (parent) parent.appendChild(e);
    return e;
  }

  /* Orbit camera: a drag turns (left or right button), a shift-drag or a middle-drag pans,
   * the wheel zooms: the same buttons in the studio's editor, where a left-drag on the
   * target paints instead. */
  function Orbit(camera, dom, onChange) {
    this.camera = camera; this.dom = dom; this.onChange = onChange;
    this.target = new THREE.Vector3(); this.radius = 100; this.theta = 0.6; this.phi = 1.0;
    // what a pointer-down does: "turn", "pan" or null (another tool handles it)
    this.modeOf = function (e) { return (e.button === 1 || e.shiftKey) ? "pan" : "turn"; };
    var self = this, last = null, mode = null;
    dom.addEventListener("contextmenu", function (e) { e.preventDefault(); });
    dom.addEventListener("pointerdown", function (e) {
      mode = self.modeOf(e);
      if (!mode) { last = null; return; }
      last = [e.clientX, e.clientY, e.clientX, e.clientY];
      if (dom.setPointerCapture) dom.setPointerCapture(e.pointerId);
    });
    dom.addEventListener("pointermove", function (e) {
      if (!last) return;
      var dx = e.clientX - last[0], dy = e.clientY - last[1];
      last[0] = e.clientX; last[1] = e.clientY;
      if (mode === "turn") {
        self.theta -= dx * 0.008;
        self.phi = Math.min(Math.PI - 0.05, Math.max(0.05, self.phi - dy * 0.008));
      } else {
        var s = self.radius * 0.0018;
        var right = new THREE.Vector3().setFromMatrixColumn(camera.matrix, 0);
        var up = new THREE.Vector3().setFromMatrixColumn(camera.matrix, 1);
        self.target.addScaledVector(right, -dx * s).addScaledVector(up, dy * s);
      }
      self.update(true);
    });
    dom.addEventListener("pointerup", function () { last = null; });
    dom.addEventListener("wheel", function (e) {
      e.preventDefault();
      self.radius *= Math.exp(e.deltaY * 0.001);
      self.update(true);
    }, {passive: false});
  }
  // view presets: from the top (+z down onto the shell), from the side, or fit()
  Orbit.prototype.preset = function (name, fit) {
    if (name === "top") this.phi = 0.02;
    else if (name === "side") this.phi = Math.PI / 2;
    else if (fit) { fit(); return this.update(true); }
    this.update(true);
  };
  Orbit.prototype.update = function (notify) {
    var c = this.camera, r = this.radius, sp = Math.sin(this.phi);
    c.position.set(this.target.x + r * sp * Math.cos(this.theta),
      this.target.y + r * sp * Math.sin(this.theta), this.target.z + r * Math.cos(this.phi));
    c.up.set(0, 0, 1);
    c.lookAt(this.target);
    c.near = r / 100; c.far = r * 100; c.updateProjectionMatrix();
    c.updateMatrixWorld();
    if (this.onChange) this.onChange(notify);
  };

  var MODES = {
    completion: {label: "completion time (s)", map: VIRIDIS},
    timing_error: {label: "timing error t_done - t* (s)", map: DIVERGING, symmetric: true},
    thickness: {label: "bracket thickness, mean of the cells (mm)", map: VIRIDIS},
    distance: {label: "distance to target (mm)", map: VIRIDIS, perFrame: true},
  };

  // A white WebGL canvas in `parent` with a camera, a sky/ground light and a sun: sets
  // obj.renderer, obj.canvas, obj.scene, obj.camera (the viewer's and the studio editor's).
  function stage(obj, parent, w, h, light) {
    obj.renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
    obj.renderer.setPixelRatio(1);
    obj.renderer.setSize(w, h);
    obj.renderer.setClearColor(0xffffff, 1);
    parent.appendChild(obj.renderer.domElement);
    obj.canvas = obj.renderer.domElement;
    obj.scene = new THREE.Scene();
    obj.camera = new THREE.PerspectiveCamera(35, w / h, 0.1, 10000);
    obj.scene.add(new THREE.HemisphereLight(0xffffff, light.ground, light.sky));
    var sun = new THREE.DirectionalLight(0xffffff, light.sun);
    sun.position.set(1, light.sunY, 3);
    obj.scene.add(sun);
  }

  // Calls fn(clientX, clientY) on a click of `dom` that does not end a drag (moved < 4 px).
  function onClick(dom, fn) {
    var down = null;
    dom.addEventListener("pointerdown", function (e) { down = [e.clientX, e.clientY]; });
    dom.addEventListener("pointerup", function (e) {
      if (down && Math.abs(e.clientX - down[0]) + Math.abs(e.clientY - down[1]) < 4) {
        fn(e.clientX, e.clientY);
      }
      down = null;
    });
  }

  // The intersections of `object` with the camera ray through the client point (x, y) of `dom`.
  function hits(dom, camera, object, x, y) {
    var r = dom.getBoundingClientRect();
    var ndc = new THREE.Vector2(((x - r.left) / r.width) * 2 - 1, -((y - r.top) / r.height) * 2 + 1);
    var ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, camera);
    return ray.intersectObject(object, false);
  }

  function MorphViewer(container, data, opts) {
    opts = opts || {};
    this.data = data; this.opts = opts; this.frame = 0; this.renderCount = 0;
    this.playing = false; this.mode = opts.mode || "completion"; this.picked = null;
    this.listeners = [];
    var nb = data.n_bases, nf = data.t.length;
    this.nf = nf;
    this.center = positions(data.center);
    this.quat = f32(data.quat);
    this.distance = f32(data.distance);
    if (data.membrane) {
      this.memPos = positions(data.membrane.pos);
      this.memTri = u32(data.membrane.tri);
      this.nMem = data.membrane.n_vertices;
    }
    container.classList.add("mv");
    this.root = container;
    var title = opts.title === undefined ? data.name : opts.title;
    if (title) el("div", {"class": "mv-title", text: title}, container);
    this.view = el("div", {"class": "mv-view"}, container);
    var bar = el("div", {"class": "mv-bar"}, container);
    this.playBtn = el("button", {"class": "mv-play", type: "button", text: "play"}, bar);
    this.slider = el("input", {"class": "mv-slider", type: "range", min: "0",
      max: String(nf - 1), step: "1", value: "0", "aria-label": "time"}, bar);
    this.timeLabel = el("span", {"class": "mv-time"}, bar);
    this.select = el("select", {"class": "mv-mode", "aria-label": "colour by"}, bar);
    for (var m in MODES) el("option", {value: m, text: MODES[m].label}, this.select);
    this.select.value = this.mode;
    this.scaleSelect = el("select", {"class": "mv-scale", "aria-label": "colour range"}, bar);
    [["morph", "range: whole morph"], ["frame", "range: this frame"],
      ["robust", "range: robust (2-98 %)"], ["fixed", "range: fixed"]].forEach(function (o) {
      el("option", {value: o[0], text: o[1]}, this.scaleSelect);
    }, this);
    this.fixedBox = el("span", {"class": "mv-fixed"}, bar);
    this.loBox = el("input", {"class": "mv-lo", type: "number", step: "any", size: "6",
      "aria-label": "colour range from"}, this.fixedBox);
    this.hiBox = el("input", {"class": "mv-hi", type: "number", step: "any", size: "6",
      "aria-label": "colour range to"}, this.fixedBox);
    this.fixedBox.hidden = true;
    ["top", "side", "reset"].forEach(function (n) {
      var b = el("button", {"class": "mv-view-" + n, type: "button", text: n,
        title: n === "reset" ? "the whole morph, from the start view" : "view from the " + n}, bar);
      b.addEventListener("click", function () { self0.preset(n); });
    });
    var self0 = this;
    this.scale = {kind: "morph", fixed: null};
    if (data.target) {
      var gl = el("label", {"class": "mv-ghost-label", title: "the target surface, " +
        "translucent: where the aligned shell should end"}, bar);
      this.ghostBox = el("input", {"class": "mv-ghost", type: "checkbox"}, gl);
      gl.appendChild(document.createTextNode(" target"));
    }
    this.legend = el("div", {"class": "mv-legend"}, container);
    this.info = el("div", {"class": "mv-info", text: "click a base to see its unit cells"},
      container);

    var w = opts.width || container.clientWidth || 640, h = opts.height || Math.round(w * 0.62);
    stage(this, this.view, w, h, {ground: 0x667788, sky: 1.6, sun: 1.4, sunY: -1.5});

    var geo = new THREE.CylinderGeometry(data.base_r, data.base_r, 2 * data.layer_h, 24);
    geo.rotateX(Math.PI / 2);   // three's cylinder axis is y; a base's axis is its flat +z
    var mat = new THREE.MeshStandardMaterial({roughness: 0.6, metalness: 0.0});
    this.bases = new THREE.InstancedMesh(geo, mat, nb);
    this.bases.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
    this.scene.add(this.bases);
    if (this.memPos) {
      var mg = new THREE.BufferGeometry();
      this.memAttr = new THREE.BufferAttribute(new Float32Array(this.nMem * 3), 3);
      this.memAttr.setUsage(THREE.DynamicDrawUsage);
      mg.setAttribute("position", this.memAttr);
      mg.setIndex(new THREE.BufferAttribute(this.memTri, 1));
      this.memGeo = mg;
      this.membrane = new THREE.Mesh(mg, new THREE.MeshStandardMaterial({
        color: 0x9a9a9a, side: THREE.DoubleSide, transparent: true, opacity: 0.55,
        roughness: 0.9, depthWrite: false}));
      this.scene.add(this.membrane);
    }
    if (data.target) {   // the target stencil: frames are aligned to it (sim/viewer.py)
      var tg = new THREE.BufferGeometry();
      tg.setAttribute("position", new THREE.BufferAttribute(positions(data.target.V), 3));
      tg.setIndex(new THREE.BufferAttribute(u32(data.target.F), 1));
      tg.computeVertexNormals();
      this.ghost = new THREE.Mesh(tg, new THREE.MeshStandardMaterial({
        color: 0x3a8fd8, side: THREE.DoubleSide, transparent: true, opacity: 0.28,
        roughness: 0.9, depthWrite: false}));
      this.ghost.renderOrder = 2;
      this.scene.add(this.ghost);
    }
    var self = this;
    this.orbit = new Orbit(this.camera, this.canvas, function (notify) {
      self.requestRender();
      if (notify) self.listeners.forEach(function (f) { f(self.getView(), self); });
    });
    this.fit();
    this.setGhost(!!opts.ghost);
    this.setColorMode(this.mode);
    this.setFrame(0);
    if (this.ghostBox) {
      this.ghostBox.addEventListener("change", function () {
        self.setGhost(self.ghostBox.checked);
        (self.group || []).forEach(function (o) { if (o !== self) o.setGhost(self.ghostBox.checked); });
      });
    }
    this.tip = el("div", {"class": "mv-tip"}, this.view);
    this.canvas.addEventListener("pointermove", function (e) {
      if (e.buttons) { self.tip.style.display = "none"; return; }
      self.hoverAt(e.clientX, e.clientY);
    });
    this.canvas.addEventListener("pointerleave", function () { self.tip.style.display = "none"; });

    this.playBtn.addEventListener("click", function () {
      if (self.playing) self.pause(); else self.play();
    });
    this.slider.addEventListener("input", function () {
      self.pause();
      self.setFrame(parseInt(self.slider.value, 10));
    });
    this.select.addEventListener("change", function () { self.setColorMode(self.select.value); });
    this.scaleSelect.addEventListener("change", function () {
      var k = self.scaleSelect.value;
      self.setScale(k, k === "fixed" ? self.range.slice() : null);
    });
    [this.loBox, this.hiBox].forEach(function (box) {
      box.addEventListener("change", function () {
        var lo = parseFloat(self.loBox.value), hi = parseFloat(self.hiBox.value);
        var ok = isFinite(lo) && isFinite(hi) && hi > lo;
        self.loBox.classList.toggle("bad", !ok); self.hiBox.classList.toggle("bad", !ok);
        if (ok) self.setScale("fixed", [lo, hi]);   // a bad pair is marked, never replaced
      });
    });
    onClick(this.canvas, function (x, y) { self.pickAt(x, y); });
  }

  MorphViewer.prototype.fit = function () {
    // bounding sphere of every frame's base centres: the camera never clips the morph
    var c = this.center, lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (var i = 0; i < c.length; i++) {
      var k = i % 3;
      if (c[i] < lo[k]) lo[k] = c[i];
      if (c[i] > hi[k]) hi[k] = c[i];
    }
    var mid = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
    var rad = 0;   // farthest base centre from the middle, over the whole morph
    for (var j = 0; j < c.length; j += 3) {
      rad = Math.max(rad, Math.hypot(c[j] - mid.x, c[j + 1] - mid.y, c[j + 2] - mid.z));
    }
    rad += this.data.base_r + this.data.layer_h;
    this.orbit.target.copy(mid);
    // the sphere fits the vertical field of view; the canvas is wider than tall
    this.orbit.radius = rad / Math.sin((this.camera.fov / 2) * Math.PI / 180) * 0.92;
    this.orbit.theta = -Math.PI / 2 + 0.5; this.orbit.phi = 0.75;
    this.orbit.update(false);
  };

  MorphViewer.prototype.setFrame = function (k) {
    k = Math.max(0, Math.min(this.nf - 1, k | 0));
    this.frame = k;
    var nb = this.data.n_bases, c = this.center, q = this.quat;
    var m = new THREE.Matrix4(), p = new THREE.Vector3(), r = new THREE.Quaternion();
    var one = new THREE.Vector3(1, 1, 1);
    for (var b = 0; b < nb; b++) {
      var o = (k * nb + b);
      p.set(c[3 * o], c[3 * o + 1], c[3 * o + 2]);
      r.set(q[4 * o], q[4 * o + 1], q[4 * o + 2], q[4 * o + 3]);
      m.compose(p, r, one);
      this.bases.setMatrixAt(b, m);
    }
    this.bases.instanceMatrix.needsUpdate = true;
    this.bases.computeBoundingSphere();
    if (this.memAttr) {
      var n3 = this.nMem * 3;
      this.memAttr.array.set(this.memPos.subarray(k * n3, (k + 1) * n3));
      this.memAttr.needsUpdate = true;
      this.memGeo.computeVertexNormals();
      this.memGeo.computeBoundingSphere();
    }
    if (MODES[this.mode].perFrame || this.scale.kind === "frame") this.colorBases();
    this.slider.value = String(k);
    this.timeLabel.textContent = "t = " + this.data.t[k].toFixed(1) + " s";
    this.requestRender();
    if (this.group && !this._syncing) {   // one time slider for the linked viewers
      var t = this.data.t[k], self = this;
      this.group.forEach(function (o) {
        if (o === self) return;
        o._syncing = true;
        try { o.setTime(t); } finally { o._syncing = false; }
      });
    }
  };

  // the frame nearest to time t (s)
  MorphViewer.prototype.setTime = function (t) {
    var ts = this.data.t, best = 0;
    for (var i = 1; i < ts.length; i++) if (Math.abs(ts[i] - t) < Math.abs(ts[best] - t)) best = i;
    this.setFrame(best);
  };

  MorphViewer.prototype.setGhost = function (on) {
    if (!this.ghost) return;
    this.ghost.visible = !!on;
    if (this.ghostBox) this.ghostBox.checked = !!on;
    this.root.setAttribute("data-ghost", on ? "1" : "0");
    this.requestRender();
  };

  MorphViewer.prototype.fieldValues = function (mode) {
    mode = mode || this.mode;
    if (mode === "distance") {
      var nb = this.data.n_bases;
      return Array.prototype.slice.call(this.distance, this.frame * nb, (this.frame + 1) * nb);
    }
    return this.data.base_fields[mode];
  };

  MorphViewer.prototype.colorBases = function () {
    var mode = MODES[this.mode], vals = this.fieldValues(), rg = this.scaleOf(this.mode);
    if (mode.symmetric && this.scale.kind !== "fixed") {
      var a = Math.max(Math.abs(rg[0]), Math.abs(rg[1])); rg = [-a, a];
    }
    var col = new THREE.Color(), out = 0, tol = 1e-9 * (rg[1] - rg[0]);
    for (var b = 0; b < vals.length; b++) {
      var v = vals[b];
      if (this.picked === b) col.setRGB(1.0, 0.1, 0.6);
      else if (!finite(v)) col.setRGB(0.55, 0.55, 0.55);
      else if (v < rg[0] - tol || v > rg[1] + tol) { col.setRGB(OUTLIER[0], OUTLIER[1], OUTLIER[2]); out++; }
      else { var c = cmap(mode.map, (v - rg[0]) / (rg[1] - rg[0])); col.setRGB(c[0], c[1], c[2]); }
      this.bases.setColorAt(b, col);
    }
    this.bases.instanceColor.needsUpdate = true;
    this.range = rg;
    this.outliers = out;
    this.root.setAttribute("data-outliers", String(out));
    this.root.setAttribute("data-range", rg[0].toFixed(4) + " " + rg[1].toFixed(4));
    this.drawLegend(mode, rg);
    this.requestRender();
  };

  // the colour range: over the whole morph, this frame only (distance changes per frame),
  // the 2nd-98th percentiles (robust), or fixed by the user; linked viewers share it
  MorphViewer.prototype.setScale = function (kind, fixed) {
    var list = this.group || [this];
    list.forEach(function (o) {   // every linked viewer first, then the colours (one scale)
      o.scale = {kind: kind, fixed: kind === "fixed" ? fixed : null};
      o.scaleSelect.value = kind;
      o.fixedBox.hidden = kind !== "fixed";
      if (kind === "fixed") {
        o.loBox.value = String(+fixed[0].toPrecision(6)); o.hiBox.value = String(+fixed[1].toPrecision(6));
      }
    });
    list.forEach(function (o) { o.colorBases(); });
  };
  MorphViewer.prototype.preset = function (name) {
    var self = this;
    this.orbit.preset(name, function () { self.fit(); });
  };

  // the colour range of a mode: over the whole morph (distance), and over every linked viewer
  MorphViewer.prototype.ownRange = function (mode) {
    var kind = this.scale.kind, robust = kind === "robust";
    if (MODES[mode].perFrame) {
      if (kind === "frame") return rangeOf(this.fieldValues(mode), false);
      var key = robust ? "_distRobust" : "_distRange";
      if (!this[key]) this[key] = rangeOf(this.distance, robust);
      return this[key];
    }
    return rangeOf(this.data.base_fields[mode], robust);
  };
  MorphViewer.prototype.scaleOf = function (mode) {
    if (this.scale.kind === "fixed" && this.scale.fixed) return this.scale.fixed.slice();
    var list = this.group || [this], lo = Infinity, hi = -Infinity;
    list.forEach(function (v) {
      var r = v.ownRange(mode);
      lo = Math.min(lo, r[0]); hi = Math.max(hi, r[1]);
    });
    return [lo, hi];
  };

  MorphViewer.prototype.drawLegend = function (mode, rg) {
    var stops = [];
    for (var i = 0; i <= 10; i++) stops.push(css(cmap(mode.map, i / 10)) + " " + (10 * i) + "%");
    this.legend.innerHTML = "";
    el("span", {text: mode.label + ": " + rg[0].toFixed(2)}, this.legend);
    var bar = el("span", {"class": "mv-ramp"}, this.legend);
    bar.style.background = "linear-gradient(90deg," + stops.join(",") + ")";
    el("span", {text: rg[1].toFixed(2) + "  (grey: no value" + (this.outliers ?
      "; orange: " + this.outliers + " beyond the range" : "") + ")"}, this.legend);
  };

  MorphViewer.prototype.setColorMode = function (mode) {
    if (!MODES[mode]) return;
    this.mode = mode; this.select.value = mode;
    this.colorBases();
    var self = this;
    if (this.group && !this._syncing) {   // one colour scale: the same mode everywhere
      this.group.forEach(function (o) {
        if (o === self) return;
        o._syncing = true;
        try { o.setColorMode(mode); } finally { o._syncing = false; }
      });
    }
  };

  MorphViewer.prototype.play = function () {
    if (this.playing) return;
    this.playing = true; this.playBtn.textContent = "pause";
    if (this.frame >= this.nf - 1) this.setFrame(0);
    var self = this, lastT = null;
    function tick(now) {
      if (!self.playing) return;
      if (lastT === null || now - lastT > 80) {
        lastT = now;
        if (self.frame >= self.nf - 1) { self.pause(); return; }
        self.setFrame(self.frame + 1);
      }
      requestAnimationFrame(tick);
    }
    requestAnimationFrame(tick);
  };
  MorphViewer.prototype.pause = function () {
    this.playing = false; this.playBtn.textContent = "play";
  };

  MorphViewer.prototype.requestRender = function () {
    if (this._pending) return;
    this._pending = true;
    var self = this;
    requestAnimationFrame(function () { self._pending = false; self.render(); });
  };
  MorphViewer.prototype.render = function () {
    this.renderer.render(this.scene, this.camera);
    this.renderCount++;
    this.root.setAttribute("data-frame", String(this.frame));
    this.root.setAttribute("data-renders", String(this.renderCount));
  };

  MorphViewer.prototype.pickAt = function (x, y) {
    var hit = hits(this.canvas, this.camera, this.bases, x, y);
    this.selectBase(hit.length ? hit[0].instanceId : null);
  };

  // per-cell details of the base under the pointer, in a tooltip
  MorphViewer.prototype.hoverAt = function (x, y) {
    var hit = hits(this.canvas, this.camera, this.bases, x, y), tip = this.tip;
    if (!hit.length) { tip.style.display = "none"; this.root.removeAttribute("data-hover"); return; }
    var b = hit[0].instanceId, c = this.data.cells, rows = this.cellsOfBase(b);
    function f(v, d) { return finite(v) ? v.toFixed(d) : "never"; }
    tip.innerHTML = "";
    el("div", {text: "base " + b}, tip);
    rows.forEach(function (i) {
      el("div", {text: "cell " + i + ": t* " + f(c.t_star[i], 1) + " s, done " +
        f(c.t_done[i], 1) + " s, h " + f(c.h_top[i], 3) + "/" + f(c.h_bottom[i], 3) + " mm" +
        (c.clamped[i] ? ", clamped" : "")}, tip);
    });
    var r = this.canvas.getBoundingClientRect();
    tip.style.left = (x - r.left + 14) + "px"; tip.style.top = (y - r.top + 10) + "px";
    tip.style.display = "block";
    this.root.setAttribute("data-hover", String(b));
  };

  MorphViewer.prototype.cellsOfBase = function (b) {
    var c = this.data.cells, out = [];
    for (var i = 0; i < c.base_a.length; i++) if (c.base_a[i] === b || c.base_b[i] === b) out.push(i);
    return out;
  };

  MorphViewer.prototype.selectBase = function (b) {
    this.picked = (b === null || b === undefined) ? null : b;
    this.colorBases();
    this.info.innerHTML = "";
    if (this.picked === null) { this.info.textContent = "click a base to see its unit cells"; return; }
    var c = this.data.cells, rows = this.cellsOfBase(b);
    el("div", {text: "base " + b + ": " + rows.length + " unit cell(s)"}, this.info);
    var tab = el("table", {"class": "mv-cells"}, this.info);
    var head = el("tr", {}, tab);
    ["cell", "bases", "t* (s)", "t_done (s)", "h top (mm)", "h bottom (mm)", "clamped"]
      .forEach(function (h) { el("th", {text: h}, head); });
    function f(v, d) { return finite(v) ? v.toFixed(d) : "never"; }
    rows.forEach(function (i) {
      var tr = el("tr", {"data-cell": String(i)}, tab);
      [String(i), c.base_a[i] + "-" + c.base_b[i], f(c.t_star[i], 1), f(c.t_done[i], 1),
        f(c.h_top[i], 3), f(c.h_bottom[i], 3), c.clamped[i] ? "yes" : "no"]
        .forEach(function (v) { el("td", {text: v}, tr); });
    });
    if (this.opts.onPick) this.opts.onPick(b, rows, this);
  };

  MorphViewer.prototype.getView = function () {
    var o = this.orbit;
    return {target: o.target.toArray(), radius: o.radius, theta: o.theta, phi: o.phi};
  };
  MorphViewer.prototype.setView = function (v) {
    var o = this.orbit;
    o.target.fromArray(v.target); o.radius = v.radius; o.theta = v.theta; o.phi = v.phi;
    o.update(false);
  };
  MorphViewer.prototype.onView = function (f) { this.listeners.push(f); };

  // one camera, one time slider and one colour scale for several viewers (side by side)
  MorphViewer.link = function (viewers) {
    viewers.forEach(function (v) {
      v.group = viewers;
      v.onView(function (view, src) {
        viewers.forEach(function (o) { if (o !== src) o.setView(view); });
      });
    });
    if (viewers.length > 1) {
      viewers.slice(1).forEach(function (o) { o.setView(viewers[0].getView()); });
      viewers[0].setColorMode(viewers[0].mode);     // every viewer on the shared scale
      viewers[0].setFrame(viewers[0].frame);
    }
  };

  // A printable part (binary STL) in 3D, with the orbit camera: {renderer, mesh, render()}
  function parseStl(buffer) {
    var dv = new DataView(buffer), n = buffer.byteLength >= 84 ? dv.getUint32(80, true) : -1;
    if (n < 0 || 84 + 50 * n !== buffer.byteLength) throw new Error("not a binary STL");
    var pos = new Float32Array(9 * n);
    for (var i = 0; i < n; i++) {
      for (var k = 0; k < 9; k++) pos[9 * i + k] = dv.getFloat32(84 + 50 * i + 12 + 4 * k, true);
    }
    return pos;
  }
  MorphViewer.partView = function (container, buffer, opts) {
    opts = opts || {};
    var obj = {}, w = opts.width || 480, h = opts.height || 320;
    stage(obj, container, w, h, {ground: 0x778899, sky: 1.8, sun: 1.2, sunY: -1});
    var g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(parseStl(buffer), 3));
    g.computeVertexNormals();
    g.computeBoundingSphere();
    obj.mesh = new THREE.Mesh(g, new THREE.MeshStandardMaterial({color: 0xd9a441,
      roughness: 0.7, flatShading: true}));
    obj.scene.add(obj.mesh);
    obj.render = function () { obj.renderer.render(obj.scene, obj.camera); };
    obj.orbit = new Orbit(obj.camera, obj.canvas, function () { obj.render(); });
    var bs = g.boundingSphere;
    obj.orbit.target.copy(bs.center);
    obj.orbit.radius = bs.radius / Math.sin(17.5 * Math.PI / 180) * 1.02;
    obj.orbit.theta = -Math.PI / 2 + 0.4; obj.orbit.phi = 0.7;
    obj.orbit.update(false);
    obj.triangles = g.getAttribute("position").count / 3;
    return obj;
  };

  // canvas pixels (for tests): fraction of non-white pixels and a checksum
  MorphViewer.prototype.pixelStats = function () {
    this.render();
    var gl = this.renderer.getContext(), w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    var px = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    var ink = 0, sum = 0;
    for (var i = 0; i < px.length; i += 4) {
      if (px[i] < 250 || px[i + 1] < 250 || px[i + 2] < 250) ink++;
      sum = (sum * 31 + px[i] + 7 * px[i + 1] + 13 * px[i + 2]) % 1000000007;
    }
    return {ink: ink / (w * h), checksum: sum, width: w, height: h};
  };

  MorphViewer.decode = {positions: positions, f32: f32, u32: u32};
  MorphViewer.cmap = function (name, x) { return cmap(name === "diverging" ? DIVERGING : VIRIDIS, x); };
  MorphViewer.Orbit = Orbit;
  MorphViewer.stage = stage;
  MorphViewer.onClick = onClick;
  MorphViewer.hits = hits;
  global.MorphViewer = MorphViewer;
})(window);
