/* morphshell studio: morph viewers side by side and the time-landscape editor.
 * Talks only to the local server that served this page (same origin, JSON). */
(function () {
  "use strict";

  var studio = {viewers: [], builds: [], editor: null};
  window.studio = studio;

  function $(id) { return document.getElementById(id); }
  function api(path, body) {
    var opt = body === undefined ? {} : {method: "POST", body: JSON.stringify(body),
      headers: {"Content-Type": "application/json"}};
    return fetch(path, opt).then(function (r) {
      return r.json().then(function (j) {
        if (!r.ok) throw new Error(j.error || ("HTTP " + r.status));
        return j;
      });
    });
  }
  function status(text, state) {
    var s = $("status");
    s.textContent = text;
    s.setAttribute("data-state", state || "idle");
  }

  // ---------------------------------------------------------------- viewers
  function loadViewers() {
    var box = $("viewers");
    box.innerHTML = "";
    studio.viewers.forEach(function (v) { v.renderer.dispose(); });
    studio.viewers = [];
    var withFrames = studio.builds.filter(function (b) { return b.has_frames; });
    var width = withFrames.length > 1 ? 520 : 760;
    return Promise.all(withFrames.map(function (b) {
      return api("/api/build/" + b.id + "/viewer").then(function (data) {
        return {b: b, data: data};
      });
    })).then(function (list) {
      list.forEach(function (x) {
        var div = document.createElement("div");
        div.id = "viewer-" + x.b.id;
        box.appendChild(div);
        studio.viewers.push(new MorphViewer(div, x.data, {width: width, title: x.b.name}));
      });
      MorphViewer.link(studio.viewers);
      if (!list.length) box.textContent = "no simulated build (run Program and simulate)";
      box.setAttribute("data-loaded", String(Date.now()));
    });
  }

  // ---------------------------------------------------------------- editor
  function Editor(container) {
    this.container = container;
    this.keyframes = [];   // {kind: "keyframe"|"brush", vertex, time, radius}
    var w = 640, h = 440;
    MorphViewer.stage(this, container, w, h, {ground: 0x778899, sky: 2.0, sun: 1.0, sunY: -1});
    var self = this;
    this.orbit = new MorphViewer.Orbit(this.camera, this.canvas, function () { self.render(); });
    MorphViewer.onClick(this.canvas, function (x, y) { self.clickAt(x, y); });
  }

  Editor.prototype.load = function (build) {
    var self = this;
    this.build = build;
    return api("/api/build/" + build.id + "/target").then(function (d) {
      self.target = d;
      var V = new Float32Array(d.V), F = new Uint32Array(d.F);
      self.V = V; self.nv = V.length / 3;
      if (self.mesh) { self.scene.remove(self.mesh); self.scene.remove(self.marks); }
      var g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(V, 3));
      g.setAttribute("color", new THREE.BufferAttribute(new Float32Array(V.length), 3));
      g.setIndex(new THREE.BufferAttribute(F, 1));
      g.computeVertexNormals();
      self.mesh = new THREE.Mesh(g, new THREE.MeshStandardMaterial({vertexColors: true,
        side: THREE.DoubleSide, roughness: 0.8, flatShading: false}));
      self.scene.add(self.mesh);
      // one point per unit cell, at the middle of its shared stencil edge
      var nc = d.vertex_a.length, P = new Float32Array(3 * nc);
      for (var c = 0; c < nc; c++) {
        for (var k = 0; k < 3; k++) {
          P[3 * c + k] = 0.5 * (V[3 * d.vertex_a[c] + k] + V[3 * d.vertex_b[c] + k]);
        }
      }
      d.mid = P;
      self.marks = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({size: 9, vertexColors: true,
        sizeAttenuation: false, transparent: true, depthTest: false}));
      self.scene.add(self.marks);
      if (!self.kfGroup) { self.kfGroup = new THREE.Group(); self.scene.add(self.kfGroup); }
      g.computeBoundingSphere();
      var bs = g.boundingSphere;
      self.orbit.target.copy(bs.center);
      self.orbit.radius = bs.radius / Math.sin(17.5 * Math.PI / 180) * 1.05;
      self.orbit.theta = -Math.PI / 2 + 0.5; self.orbit.phi = 0.8;
      self.orbit.update(false);
      if (self.sourceOf !== build.id && !self.keyframes.length && d.source) {
        (d.source.keyframes || []).forEach(function (k) {
          self.keyframes.push({kind: "keyframe", vertex: k.vertex, time: k.time});
        });
        (d.source.brushes || []).forEach(function (b) {
          self.keyframes.push({kind: "brush", vertex: b.vertex, time: b.time, radius: b.radius});
        });
      }
      self.sourceOf = build.id;
      self.show(d.landscape, d.feasibility, d.programmed_clamped);
      self.listKeyframes();
    });
  };

  Editor.prototype.payload = function () {
    var kf = [], br = [];
    this.keyframes.forEach(function (k) {
      if (k.kind === "brush") br.push({vertex: k.vertex, radius: k.radius, time: k.time});
      else kf.push({vertex: k.vertex, time: k.time});
    });
    return {keyframes: kf, brushes: br};
  };

  Editor.prototype.show = function (land, feas, programmed) {
    this.landscape = land; this.feas = feas;
    if (programmed) this.programmed = programmed;
    var lo = Infinity, hi = -Infinity, i;
    for (i = 0; i < land.length; i++) { lo = Math.min(lo, land[i]); hi = Math.max(hi, land[i]); }
    if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
    var col = this.mesh.geometry.getAttribute("color");
    for (i = 0; i < land.length; i++) {
      var c = MorphViewer.cmap("viridis", (land[i] - lo) / (hi - lo));
      col.setXYZ(i, c[0], c[1], c[2]);
    }
    col.needsUpdate = true;
    // only the cells that cannot reach their time get a point: red too early, blue too late
    var mid = this.target.mid, pts = [], cols = [], nearly = 0, late = 0;
    for (i = 0; i < feas.side.length; i++) {
      var s = feas.side[i];
      if (!s) continue;
      pts.push(mid[3 * i], mid[3 * i + 1], mid[3 * i + 2]);
      if (s < 0) { cols.push(0.9, 0.05, 0.05); nearly++; } else { cols.push(0.1, 0.3, 1.0); late++; }
    }
    var pg = this.marks.geometry;
    pg.setAttribute("position", new THREE.BufferAttribute(new Float32Array(pts), 3));
    pg.setAttribute("color", new THREE.BufferAttribute(new Float32Array(cols), 3));
    pg.computeBoundingSphere();
    var f = $("feas");
    var progN = (this.programmed || []).reduce(function (a, b) { return a + b; }, 0);
    f.setAttribute("data-n-clamped", String(feas.n_clamped));
    f.setAttribute("data-programmed-clamped", String(progN));
    f.textContent = feas.n_clamped + " of " + feas.side.length + " cells cannot reach their " +
      "time (" + nearly + " too early, red; " + late + " too late, blue). Programmed " +
      "(cells.csv): " + progN + " clamped.";
    var leg = $("legend-editor");
    leg.innerHTML = "";
    var stops = [];
    for (i = 0; i <= 10; i++) {
      var cc = MorphViewer.cmap("viridis", i / 10);
      stops.push("rgb(" + cc.map(function (x) { return Math.round(255 * x); }).join(",") +
        ") " + (10 * i) + "%");
    }
    leg.appendChild(document.createTextNode("landscape " + lo.toFixed(1) + " s "));
    var ramp = document.createElement("span");
    ramp.className = "mv-ramp";
    ramp.style.background = "linear-gradient(90deg," + stops.join(",") + ")";
    leg.appendChild(ramp);
    leg.appendChild(document.createTextNode(" " + hi.toFixed(1) + " s"));
    this.drawKeyframes();
    this.render();
  };

  Editor.prototype.drawKeyframes = function () {
    var g = this.kfGroup, V = this.V, self = this;
    while (g.children.length) g.remove(g.children[0]);
    this.keyframes.forEach(function (k) {
      var r = k.kind === "brush" ? k.radius : 1.2;
      var m = new THREE.Mesh(new THREE.SphereGeometry(k.kind === "brush" ? 1.0 : 1.2, 16, 12),
        new THREE.MeshBasicMaterial({color: 0x111111}));
      m.position.set(V[3 * k.vertex], V[3 * k.vertex + 1], V[3 * k.vertex + 2]);
      g.add(m);
      if (k.kind === "brush") {
        var ring = new THREE.Mesh(new THREE.SphereGeometry(r, 24, 16),
          new THREE.MeshBasicMaterial({color: 0x111111, wireframe: true, transparent: true,
            opacity: 0.25}));
        ring.position.copy(m.position);
        g.add(ring);
      }
    });
    self.render();
  };

  Editor.prototype.listKeyframes = function () {
    var tb = $("kf-list"), self = this;
    tb.innerHTML = "";
    this.keyframes.forEach(function (k, i) {
      var tr = document.createElement("tr");
      tr.setAttribute("data-vertex", String(k.vertex));
      tr.setAttribute("data-time", String(k.time));
      [k.kind + (k.kind === "brush" ? " " + k.radius + " mm" : ""), String(k.vertex)]
        .forEach(function (t) { var td = document.createElement("td"); td.textContent = t; tr.appendChild(td); });
      var td = document.createElement("td"), inp = document.createElement("input");
      inp.type = "number"; inp.value = String(k.time); inp.min = "0"; inp.max = "1000";
      inp.addEventListener("change", function () {
        var v = parseFloat(inp.value);
        if (isFinite(v)) { k.time = v; tr.setAttribute("data-time", String(v)); self.update(); }
      });
      td.appendChild(inp); tr.appendChild(td);
      var del = document.createElement("button");
      del.type = "button"; del.textContent = "x"; del.title = "remove";
      del.addEventListener("click", function () { self.keyframes.splice(i, 1); self.listKeyframes(); self.update(); });
      td = document.createElement("td"); td.appendChild(del); tr.appendChild(td);
      tb.appendChild(tr);
    });
    tb.setAttribute("data-count", String(this.keyframes.length));
  };

  Editor.prototype.update = function () {
    var self = this, seq = (this.seq = (this.seq || 0) + 1);
    if (!this.keyframes.length) {
      return this.load(this.build);
    }
    return api("/api/build/" + this.build.id + "/preview", this.payload()).then(function (r) {
      if (seq !== self.seq) return;   // a newer edit is on its way
      self.show(r.landscape, r.feasibility);
      $("feas").setAttribute("data-seq", String(seq));
    }).catch(function (e) { status(e.message, "error"); });
  };

  Editor.prototype.vertexAt = function (x, y) {
    var hit = MorphViewer.hits(this.canvas, this.camera, this.mesh, x, y);
    if (!hit.length) return null;
    var f = hit[0].face, V = this.V, best = null, bd = Infinity;
    [f.a, f.b, f.c].forEach(function (v) {
      var d = Math.hypot(V[3 * v] - hit[0].point.x, V[3 * v + 1] - hit[0].point.y,
        V[3 * v + 2] - hit[0].point.z);
      if (d < bd) { bd = d; best = v; }
    });
    return best;
  };

  // client coordinates of a vertex (tests click there)
  Editor.prototype.screenOf = function (v) {
    var p = new THREE.Vector3(this.V[3 * v], this.V[3 * v + 1], this.V[3 * v + 2]);
    p.project(this.camera);
    var r = this.canvas.getBoundingClientRect();
    return [r.left + (p.x + 1) / 2 * r.width, r.top + (1 - p.y) / 2 * r.height];
  };

  Editor.prototype.clickAt = function (x, y) {
    var v = this.vertexAt(x, y);
    if (v === null) return;
    var t = parseFloat($("kf-time").value);
    if (!isFinite(t)) { status("set a time first", "error"); return; }
    var tool = document.querySelector("input[name=tool]:checked").value;
    var k = {kind: tool, vertex: v, time: t};
    if (tool === "brush") k.radius = parseFloat($("brush-radius").value) || 5;
    this.keyframes = this.keyframes.filter(function (o) { return !(o.kind === k.kind && o.vertex === v); });
    this.keyframes.push(k);
    this.listKeyframes();
    this.update();
  };

  Editor.prototype.render = function () {
    this.renderer.render(this.scene, this.camera);
    this.container.setAttribute("data-renders", String((this.renders = (this.renders || 0) + 1)));
  };

  // ---------------------------------------------------------------- actions
  function save() {
    var ed = studio.editor;
    if (!ed.keyframes.length) { status("place a keyframe first", "error"); return Promise.resolve(); }
    status("saving ...", "busy");
    return api("/api/build/" + ed.build.id + "/save", ed.payload()).then(function (r) {
      status("saved " + r.written + " (" + r.range_s[0].toFixed(1) + "-" +
        r.range_s[1].toFixed(1) + " s)", "saved");
    }).catch(function (e) { status(e.message, "error"); });
  }

  function run(stages) {
    var ed = studio.editor;
    var go = ed.keyframes.length ? save() : Promise.resolve();
    return go.then(function () {
      if ($("status").getAttribute("data-state") === "error") return;
      return api("/api/build/" + ed.build.id + "/run", {stages: stages}).then(poll);
    }).catch(function (e) { status(e.message, "error"); });
  }

  function poll() {
    return api("/api/job").then(function (j) {
      $("progress").value = j.progress;
      if (j.state === "running") {
        status(j.message, "running");
        return new Promise(function (res) { setTimeout(res, 400); }).then(poll);
      }
      if (j.state === "error") { status(j.error, "error"); return; }
      status("reloading ...", "running");
      var reload = [studio.editor.load(studio.editor.build)];
      if (j.stages === "program+simulate") {
        reload.push(api("/api/builds").then(function (b) { studio.builds = b; return loadViewers(); }));
      }
      return Promise.all(reload).then(function () { status(j.stages + ": done", "done"); });
    });
  }

  function init() {
    api("/api/builds").then(function (builds) {
      studio.builds = builds;
      $("builds-note").textContent = builds.map(function (b) { return b.path; }).join(" | ");
      var sel = $("edit-build");
      builds.forEach(function (b) {
        var o = document.createElement("option");
        o.value = String(b.id); o.textContent = b.name; sel.appendChild(o);
      });
      studio.editor = new Editor($("editor-view"));
      sel.addEventListener("change", function () {
        studio.editor.keyframes = [];
        studio.editor.listKeyframes();
        studio.editor.load(builds[parseInt(sel.value, 10)]);
      });
      $("save").addEventListener("click", save);
      $("program").addEventListener("click", function () { run("program"); });
      $("run").addEventListener("click", function () { run("program+simulate"); });
      $("clear").addEventListener("click", function () {
        studio.editor.keyframes = []; studio.editor.listKeyframes(); studio.editor.update();
      });
      return Promise.all([loadViewers(), studio.editor.load(builds[0])]);
    }).then(function () {
      document.body.setAttribute("data-ready", "1");
    }).catch(function (e) {
      status(e.message, "error");
      document.body.setAttribute("data-ready", "error");
    });
  }
  init();
})();
