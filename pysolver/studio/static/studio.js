/* morphshell studio: paint the time landscape on the target, build it again, and compare.
 * Talks only to the local server that served this page (same origin, JSON), through boot.js
 * (the token, the calls, the first requests). */
(function () {
  "use strict";

  // the server's limits (pysolver.params.Limits), sent with each build's target
  var MAX_TIME = 1000, MAX_RADIUS = 1000;
  // (started: ms from the navigation to this file running, after three.js: the first paint's
  // breakdown in docs/results.md)
  var studio = {viewers: [], builds: [], editor: null, token: null, job: null,
    started: Math.round(performance.now())};
  window.studio = studio;

  function $(id) { return document.getElementById(id); }
  // the network side (token, JSON calls, session cookie) and the first requests, which went
  // out while this file and three.js loaded: boot.js
  var net = window.studioNet, api = net.api, headers = net.headers;
  function status(text, state) {
    var s = $("status");
    s.textContent = text;
    s.setAttribute("data-state", state || "idle");
  }
  // errors of actions (run, preview, keyframes): shown until the next success of that kind
  var errors = {};
  function showErrors() {
    var box = $("error"), keys = Object.keys(errors).filter(function (k) { return errors[k]; });
    box.textContent = keys.map(function (k) { return errors[k]; }).join(" | ");
    box.setAttribute("data-kinds", keys.join(" "));
  }
  function setError(kind, text) { errors[kind] = text || null; showErrors(); }
  function fmt(v, d) { return (v === null || v === undefined || !isFinite(v)) ? "n/a" : Number(v).toFixed(d); }
  function el(tag, attrs, parent) {
    var e = document.createElement(tag);
    for (var k in attrs || {}) {
      if (k === "text") e.textContent = attrs[k]; else e.setAttribute(k, attrs[k]);
    }
    if (parent) parent.appendChild(e);
    return e;
  }

  // a number input checked as the user types: the message says what is wrong, and goes
  // away when the value is fixed (never a silent replacement)
  function numberField(id, errId, rule) {
    var inp = $(id);
    function check() {
      var raw = inp.value.trim(), msg = null, v = parseFloat(raw);
      if (inp.disabled) msg = null;
      else if (raw === "" || !isFinite(v) || !/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(raw)) {
        msg = rule.name + ": give a number" + (raw === "" ? "" : " (\"" + raw + "\" is not one)");
      } else msg = rule.check(v);
      inp.classList.toggle("bad", !!msg);
      inp.setAttribute("aria-invalid", msg ? "true" : "false");
      return {ok: !msg, value: v, message: msg};
    }
    inp.addEventListener("input", function () { rule.changed(); });
    inp.addEventListener("change", function () { rule.changed(); });
    return {check: check, input: inp};
  }

  // ---------------------------------------------------------------- viewers
  function loadViewers() {
    var box = $("viewers");
    var keep = {};   // camera, time, picked base, colour mode and ghost survive a reload
    studio.viewers.forEach(function (v) {
      keep[v.buildId] = {view: v.getView(), t: v.data.t[v.frame], picked: v.picked,
        mode: v.mode, ghost: v.ghost ? v.ghost.visible : true, scale: v.scale};
    });
    var withFrames = studio.builds.filter(function (b) { return b.has_frames; });
    var width = withFrames.length > 1 ? 520 : 760;
    // the data arrive progressively: until the first viewers are shown, how much has come
    var got = {}, total = {};
    function shown(id, k, n) {
      got[id] = k; total[id] = n;
      if (studio.viewers.length) return;
      var sum = function (o) { return Object.keys(o).reduce(function (a, i) { return a + o[i]; }, 0); };
      var a = sum(got), t = sum(total);
      box.textContent = "loading the morph viewer: " + (a / 1e6).toFixed(1) +
        (t ? " of " + (t / 1e6).toFixed(1) : "") + " MB";
      box.setAttribute("data-received", String(a));
    }
    return Promise.all(withFrames.map(function (b) {
      return net.apiRead("/api/build/" + b.id + "/viewer", function (k, n) { shown(b.id, k, n); })
        .then(function (data) { return {b: b, data: data}; });
    })).then(function (list) {
      studio.viewers.forEach(function (v) { v.renderer.dispose(); });
      studio.viewers = [];
      box.innerHTML = "";
      list.forEach(function (x) {
        var div = document.createElement("div");
        div.id = "viewer-" + x.b.id;
        box.appendChild(div);
        var k = keep[x.b.id];
        var v = new MorphViewer(div, x.data, {width: width, title: x.b.name,
          ghost: k ? k.ghost : true, mode: k ? k.mode : undefined});
        v.buildId = x.b.id;
        studio.viewers.push(v);
      });
      MorphViewer.link(studio.viewers);
      studio.viewers.forEach(function (v) {
        var k = keep[v.buildId];
        if (!k) return;
        v.setView(k.view);
        v.setTime(k.t);
        if (k.scale.kind !== "morph") v.setScale(k.scale.kind, k.scale.fixed);
        if (k.picked !== null && k.picked < v.data.n_bases) v.selectBase(k.picked);
      });
      if (!list.length) box.textContent = "no simulated build (press Run)";
      box.setAttribute("data-loaded", String(Date.now()));
    });
  }

  // ---------------------------------------------------------------- editor
  function Editor(container) {
    this.container = container;
    this.states = {};     // per build: landscape, undo/redo, edit log, keyframes
    var w = 640, h = 460, self = this;
    MorphViewer.stage(this, container, w, h, {ground: 0x778899, sky: 2.0, sun: 1.0, sunY: -1});
    this.orbit = new MorphViewer.Orbit(this.camera, this.canvas, function () { self.render(); });
    this.orbit.modeOf = function (e) {
      var tool = self.tool();
      if (e.shiftKey || e.button === 1) return "pan";   // the viewer's buttons (Orbit)
      if (e.button === 2) return "turn";
      if (e.button !== 0) return null;
      if (tool === "look") return "turn";
      if (tool === "brush" && !self.hitPoint(e.clientX, e.clientY)) return "turn";  // off the target
      return null;
    };
    this.canvas.addEventListener("pointerdown", function (e) { self.pointerDown(e); });
    this.canvas.addEventListener("pointermove", function (e) { self.pointerMove(e); });
    this.canvas.addEventListener("pointerup", function (e) { self.pointerUp(e); });
    this.canvas.addEventListener("pointerleave", function () { $("hover").style.display = "none"; self.hovered = null; });
    MorphViewer.onClick(this.canvas, function (x, y) {
      if (self.tool() === "keyframe") self.clickAt(x, y);
    });
  }

  Editor.prototype.tool = function () {
    return document.querySelector("input[name=tool]:checked").value;
  };

  // Load a build into the editor.  Until its target arrives every control that writes is
  // disabled (studio.loading), and a late answer for a build no longer selected is dropped:
  // the landscape on screen, the state edited and the build a Run goes to are always one.
  // opts.keepCamera keeps the view; opts.state replaces the build's editing state;
  // opts.target is the target's request, already sent (the first build's, by boot.js).
  Editor.prototype.load = function (build, opts) {
    var self = this, seq = (this.loadSeq = (this.loadSeq || 0) + 1);
    opts = opts || {};
    studio.loading = build.id;
    this.updateButtons();
    return (opts.target || api("/api/build/" + build.id + "/target")).then(function (d) {
      if (seq !== self.loadSeq) return;      // another build was selected meanwhile
      self.build = build;
      self.target = d;
      MAX_TIME = d.limits.max_time_s; MAX_RADIUS = d.limits.max_radius_mm;
      var V = new Float32Array(d.V), F = new Uint32Array(d.F);
      self.V = V; self.F = F; self.nv = V.length / 3;
      if (self.mesh) { self.scene.remove(self.mesh); self.scene.remove(self.marks); }
      var g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(V, 3));
      g.setAttribute("color", new THREE.BufferAttribute(new Float32Array(V.length), 3));
      g.setIndex(new THREE.BufferAttribute(F, 1));
      g.computeVertexNormals();
      self.mesh = new THREE.Mesh(g, new THREE.MeshStandardMaterial({vertexColors: true,
        side: THREE.DoubleSide, roughness: 0.8}));
      self.scene.add(self.mesh);
      // neighbours (smoothing) and the middle of each cell's shared edge (marks, hover)
      var nb = [], i, c;
      for (i = 0; i < self.nv; i++) nb.push({});
      for (i = 0; i < F.length; i += 3) {
        for (var k = 0; k < 3; k++) {
          var a = F[i + k], b = F[i + (k + 1) % 3];
          nb[a][b] = 1; nb[b][a] = 1;
        }
      }
      self.neighbours = nb.map(function (o) { return Object.keys(o).map(Number); });
      var nc = d.vertex_a.length, P = new Float32Array(3 * nc);
      self.cellsOf = [];
      for (i = 0; i < self.nv; i++) self.cellsOf.push([]);
      for (c = 0; c < nc; c++) {
        for (var j = 0; j < 3; j++) P[3 * c + j] = 0.5 * (V[3 * d.vertex_a[c] + j] + V[3 * d.vertex_b[c] + j]);
        self.cellsOf[d.vertex_a[c]].push(c); self.cellsOf[d.vertex_b[c]].push(c);
      }
      d.mid = P;
      self.marks = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({
        size: 8, vertexColors: true, sizeAttenuation: false, transparent: true, depthTest: false}));
      self.scene.add(self.marks);
      if (!self.kfGroup) { self.kfGroup = new THREE.Group(); self.scene.add(self.kfGroup); }
      if (!self.strokeMark) {
        self.strokeMark = new THREE.Mesh(new THREE.SphereGeometry(1, 20, 14),
          new THREE.MeshBasicMaterial({color: 0x111111, wireframe: true, transparent: true, opacity: 0.35}));
        self.strokeMark.visible = false;
        self.scene.add(self.strokeMark);
      }
      g.computeBoundingSphere();
      if (!opts.keepCamera || self.fittedFor !== build.id) {
        self.fit();
        self.fittedFor = build.id;
      }
      self.orbit.update(false);
      self.buildLand = Float64Array.from(d.landscape);
      var st = opts.state || self.states[build.id];
      // a state edited from another landscape of this build (built again since) is not kept
      if (!st || st.base !== d.landscape_sha256) {
        st = {land: Float64Array.from(d.landscape), undo: [], redo: [], edits: [], keyframes: []};
      }
      st.id = build.id; st.name = d.build; st.base = d.landscape_sha256;
      self.states[build.id] = self.st = st;
      if (studio.loading === build.id) studio.loading = null;
      self.fixScale(null);     // the build's own range, fixed while painting
      self.version = (self.version || 0) + 1;
      self.feas = d.feasibility;
      // the target came with the feasibility of the build's own landscape: asked again only
      // for a kept state edited away from it
      if (sameLandscape(st.land, self.buildLand)) {
        self.previewed = self.version; self.previewedFor = st;
        self.lastPreview = Promise.resolve();
        self.seq = (self.seq || 0) + 1;    // a reply still on its way is for another landscape
        $("feas").setAttribute("data-seq", String(self.seq));
      }
      self.listKeyframes();
      self.paint();
      self.updateButtons();
      return self.preview();
    });
  };
  function sameLandscape(a, b) {
    if (a.length !== b.length) return false;
    for (var i = 0; i < a.length; i++) if (a[i] !== b[i]) return false;
    return true;
  }

  Editor.prototype.fit = function () {
    var bs = this.mesh.geometry.boundingSphere;
    this.orbit.target.copy(bs.center);
    this.orbit.radius = bs.radius / Math.sin(17.5 * Math.PI / 180) * 1.05;
    this.orbit.theta = -Math.PI / 2 + 0.5; this.orbit.phi = 0.8;
  };

  // ------------------------------------------------ history: undo restores byte for byte
  Editor.prototype.snapshot = function () {
    var st = this.st;
    return {land: Float64Array.from(st.land), edits: st.edits.slice(),
      keyframes: st.keyframes.map(function (k) { return Object.assign({}, k); })};
  };
  Editor.prototype.restore = function (s) {
    this.st.land = Float64Array.from(s.land);
    this.st.edits = s.edits.slice();
    this.st.keyframes = s.keyframes.map(function (k) { return Object.assign({}, k); });
  };
  Editor.prototype.remember = function () {
    this.st.undo.push(this.snapshot());
    this.st.redo = [];
  };
  Editor.prototype.undo = function () {
    if (!this.st.undo.length) return;
    this.st.redo.push(this.snapshot());
    this.restore(this.st.undo.pop());
    this.changed("undone");
  };
  Editor.prototype.redo = function () {
    if (!this.st.redo.length) return;
    this.st.undo.push(this.snapshot());
    this.restore(this.st.redo.pop());
    this.changed("redone");
  };
  Editor.prototype.reset = function () {
    this.remember();
    this.st.land = Float64Array.from(this.buildLand);
    this.st.keyframes = [];
    this.st.edits.push({tool: "reset", mode: "build"});
    this.changed("back to the build's landscape");
  };
  Editor.prototype.changed = function (what) {
    this.version++;
    this.listKeyframes();
    this.paint();
    this.updateButtons();
    if (what) status(what, "idle");
    return this.preview();
  };
  Editor.prototype.dirty = function () { return this.st && this.st.undo.length > 0; };
  // controls that write are disabled while a build loads or runs; the brush, undo and redo
  // stay live during a run: what they change is a pending draft (drawDraft)
  Editor.prototype.updateButtons = function () {
    var running = !!(studio.job && studio.job.state === "running");
    var loading = studio.loading !== null && studio.loading !== undefined;
    var st = this.st || {undo: [], redo: []};
    $("undo").disabled = !st.undo.length || loading;
    $("redo").disabled = !st.redo.length || loading;
    ["run", "reset", "import", "edit-build", "variant", "variant-name"].forEach(function (id) {
      $(id).disabled = running || loading;
    });
    $("variant-name").disabled = $("variant-name").disabled || !$("variant").checked;
    document.body.setAttribute("data-loading", loading ? "1" : "0");
    this.container.setAttribute("data-undo", String(st.undo.length));
    this.drawDraft();
  };
  // the edit made during a run (on the build being run): shown, and kept after the run
  Editor.prototype.draft = function () {
    var sent = studio.sent, st = this.st;
    if (!sent || !st || sent.id !== st.id || sent.variant) return 0;
    return this.draftOf(st, sent);
  };
  Editor.prototype.drawDraft = function () {
    var box = $("draft"), n = this.draft();
    box.hidden = !n;
    box.setAttribute("data-vertices", String(n));
    box.textContent = n ? "Pending draft: " + n + " vertices changed since the Run started. " +
      "They are not in this run and are kept after it (Run again to build them)." : "";
  };

  // ------------------------------------------------ picking
  Editor.prototype.hitPoint = function (x, y) {
    if (!this.mesh) return null;
    var hit = MorphViewer.hits(this.canvas, this.camera, this.mesh, x, y);
    return hit.length ? hit[0] : null;
  };
  // the vertex under a client point: the nearest corner of the triangle hit, else (a click
  // on the rim, where the ray can miss the surface) the nearest vertex within 10 px on screen
  Editor.prototype.vertexAt = function (x, y) {
    var hit = this.hitPoint(x, y), V = this.V, best = null, bd = Infinity;
    if (hit) {
      var f = hit.face;
      [f.a, f.b, f.c].forEach(function (v) {
        var d = Math.hypot(V[3 * v] - hit.point.x, V[3 * v + 1] - hit.point.y, V[3 * v + 2] - hit.point.z);
        if (d < bd) { bd = d; best = v; }
      });
      return {vertex: best, px: 0};
    }
    for (var v = 0; v < this.nv; v++) {
      var s = this.screenOf(v), d = Math.hypot(s[0] - x, s[1] - y);
      if (d < bd) { bd = d; best = v; }
    }
    return bd <= 10 ? {vertex: best, px: bd} : {vertex: null, px: bd};
  };
  // client coordinates of a vertex (tests click there)
  Editor.prototype.screenOf = function (v) {
    var p = new THREE.Vector3(this.V[3 * v], this.V[3 * v + 1], this.V[3 * v + 2]);
    p.project(this.camera);
    var r = this.canvas.getBoundingClientRect();
    return [r.left + (p.x + 1) / 2 * r.width, r.top + (1 - p.y) / 2 * r.height];
  };

  // ------------------------------------------------ brush
  Editor.prototype.brush = function () {
    var mode = $("brush-mode").value, out = {mode: mode}, errs = [];
    [["value", studio.fields.value], ["radius", studio.fields.radius],
      ["falloff", studio.fields.falloff]].forEach(function (p) {
      var r = p[1].check();
      if (!r.ok) errs.push(r.message); else out[p[0]] = r.value;
    });
    $("brush-error").textContent = errs.join("; ");
    out.ok = !errs.length;
    if (out.ok) setError("brush", null);     // its cause is fixed: the message goes
    return out;
  };
  // weight of a vertex at distance d from a dab: 1 inside (1 - falloff) r, then a smooth
  // step down to 0 at r
  function weight(d, r, falloff) {
    if (d >= r) return 0;
    var inner = r * (1 - falloff);
    if (d <= inner) return 1;
    var u = (d - inner) / (r - inner);
    return 1 - u * u * (3 - 2 * u);
  }
  Editor.prototype.pointerDown = function (e) {
    if (this.tool() !== "brush" || e.button !== 0 || e.shiftKey) return;
    if (studio.loading !== null && studio.loading !== undefined) return;   // no state yet
    var hit = this.hitPoint(e.clientX, e.clientY);
    if (!hit) return;   // off the target: the orbit turns the view
    var b = this.brush();
    if (!b.ok) {
      setError("brush", "the brush did not paint: " + $("brush-error").textContent);
      return;
    }
    setError("brush", null);
    var st = this.st, n = this.nv, i;
    this.stroke = {b: b, L0: Float64Array.from(st.land), W: new Float64Array(n), points: [],
      before: this.snapshot()};
    if (b.mode === "smooth") {   // two rounds of neighbour averaging of the landscape
      var S = Float64Array.from(st.land);
      for (var it = 0; it < 2; it++) {
        var T = new Float64Array(n);
        for (i = 0; i < n; i++) {
          var nb = this.neighbours[i], s = 0;
          for (var k = 0; k < nb.length; k++) s += S[nb[k]];
          T[i] = nb.length ? 0.5 * S[i] + 0.5 * s / nb.length : S[i];
        }
        S = T;
      }
      this.stroke.S = S;
    }
    if (this.canvas.setPointerCapture) this.canvas.setPointerCapture(e.pointerId);
    this.dab(hit.point);
  };
  Editor.prototype.pointerMove = function (e) {
    if (this.stroke) {
      var hit = this.hitPoint(e.clientX, e.clientY);
      if (hit) this.dab(hit.point);
      return;
    }
    if (!e.buttons) this.hover(e.clientX, e.clientY);
  };
  Editor.prototype.pointerUp = function () {
    var sk = this.stroke;
    if (!sk) return;
    this.stroke = null;
    this.strokeMark.visible = false;
    var n = 0;
    for (var i = 0; i < this.nv; i++) if (sk.W[i] > 0) n++;
    if (!n) {
      this.restore(sk.before);
      status("the stroke reached no vertex of the target (radius " + sk.b.radius +
        " mm): nothing changed; use a larger radius", "error");
      this.paint();
      return;
    }
    this.st.undo.push(sk.before);
    this.st.redo = [];
    var rec = {tool: "brush", mode: sk.b.mode, radius: sk.b.radius, falloff: sk.b.falloff,
      vertices: n};
    if (sk.b.mode !== "smooth") rec.value = sk.b.value;
    this.st.edits.push(rec);
    this.lastStroke = {points: sk.points, radius: sk.b.radius, falloff: sk.b.falloff,
      mode: sk.b.mode, value: sk.b.value, before: Array.from(sk.L0), vertices: n};
    this.container.setAttribute("data-strokes", String((this.strokes = (this.strokes || 0) + 1)));
    status(sk.b.mode + ": " + n + " vertices changed" + (this.held ? "; " + this.held : ""), "idle");
    this.updateButtons();
    this.preview();     // the release's one request (a pending one is cancelled, a repeat skipped)
  };
  Editor.prototype.dab = function (p) {
    var sk = this.stroke, b = sk.b, V = this.V, pts = [[p.x, p.y, p.z]];
    var last = sk.points.length ? sk.points[sk.points.length - 1] : null;
    if (last) {   // dabs at most a third of the radius apart along the drag
      var gap = Math.hypot(p.x - last[0], p.y - last[1], p.z - last[2]);
      var steps = Math.min(64, Math.floor(gap / (b.radius / 3)));
      pts = [];
      for (var s = 1; s <= steps; s++) {
        var u = s / (steps + 1);
        pts.push([last[0] + u * (p.x - last[0]), last[1] + u * (p.y - last[1]), last[2] + u * (p.z - last[2])]);
      }
      pts.push([p.x, p.y, p.z]);
    }
    var W = sk.W, L0 = sk.L0, land = this.st.land, held = 0, moved = false, i;
    pts.forEach(function (q) {
      sk.points.push(q);
      for (var v = 0; v < W.length; v++) {
        var d = Math.hypot(V[3 * v] - q[0], V[3 * v + 1] - q[1], V[3 * v + 2] - q[2]);
        var w = weight(d, b.radius, b.falloff);
        if (w > W[v]) W[v] = w;
      }
    });
    // the stroke's result from the landscape before it: a vertex keeps its value exactly
    // unless the brush reached it (weight > 0), however often the drag passes
    for (i = 0; i < W.length; i++) {
      if (!(W[i] > 0)) continue;
      var goal = b.mode === "set" ? b.value : b.mode === "add" ? L0[i] + b.value :
        b.mode === "subtract" ? L0[i] - b.value : sk.S[i];
      var t = L0[i] + W[i] * (goal - L0[i]);
      if (t < 0) { t = 0; held++; } else if (t > MAX_TIME) { t = MAX_TIME; held++; }
      if (land[i] !== t) { land[i] = t; moved = true; }
    }
    this.held = held ? held + " vertices held at the limit (0-" + MAX_TIME + " s)" : "";
    this.strokeMark.position.set(p.x, p.y, p.z);
    this.strokeMark.scale.setScalar(b.radius);
    this.strokeMark.visible = true;
    if (!moved) { this.render(); return; }   // the same landscape: nothing new to ask about
    this.version++;
    this.paint();
    this.previewSoon();
  };

  // ------------------------------------------------ keyframes
  Editor.prototype.clickAt = function (x, y) {
    var at = this.vertexAt(x, y);
    if (at.vertex === null) {
      // an action error: it stays (a late preview reply does not clear it) until a click lands
      setError("click", "no vertex under the pointer (the nearest is " + Math.round(at.px) +
        " px away): click on the target surface");
      return;
    }
    setError("click", null);
    var r = studio.fields.kfTime.check();
    if (!r.ok) { $("kf-error").textContent = r.message; status("keyframe not placed: " + r.message, "error"); return; }
    this.remember();
    var v = at.vertex;
    this.st.keyframes = this.st.keyframes.filter(function (o) { return o.vertex !== v; });
    this.st.keyframes.push({vertex: v, time: r.value, raw: String(r.value)});
    status("keyframe at vertex " + v + (at.px ? " (the rim vertex nearest the click, " +
      Math.round(at.px) + " px)" : ""), "idle");
    this.interpolate();
  };
  function keyframeProblem(k) {
    var raw = String(k.raw).trim(), v = parseFloat(raw);
    if (raw === "") return "no time";
    if (!isFinite(v) || !/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(raw)) return "\"" + raw + "\" is not a number";
    if (v < 0 || v > MAX_TIME) return "time " + v + " s is outside 0-" + MAX_TIME + " s";
    return null;
  }
  // the landscape through the keyframes that are valid (bad rows are marked and skipped)
  Editor.prototype.interpolate = function () {
    var self = this, good = [], bad = 0, seq = (this.kfSeq = (this.kfSeq || 0) + 1);
    this.st.keyframes.forEach(function (k) {
      k.problem = keyframeProblem(k);
      if (k.problem) bad++; else { k.time = parseFloat(k.raw); good.push({vertex: k.vertex, time: k.time}); }
    });
    this.listKeyframes();
    function done() { $("kf-list").setAttribute("data-done", String(seq)); }
    if (!good.length) {
      status(bad ? "every keyframe row has a problem (marked): the landscape is unchanged" :
        "no keyframe: the landscape is unchanged", "idle");
      done();
      return Promise.resolve();
    }
    return api("/api/build/" + this.build.id + "/keyframes", {keyframes: good}).then(function (r) {
      if (seq !== self.kfSeq) return;
      setError("keyframes", null);
      self.st.land = Float64Array.from(r.landscape);
      self.st.edits.push({tool: "keyframes", mode: "harmonic", keyframes: good.length});
      var p = self.changed(good.length + " keyframe(s) interpolated" + (bad ? "; " + bad + " marked row(s) skipped" : ""));
      done();
      return p;
    }).catch(function (e) { setError("keyframes", e.message); done(); });
  };
  Editor.prototype.listKeyframes = function () {
    var tb = $("kf-list"), self = this;
    tb.innerHTML = "";
    (this.st ? this.st.keyframes : []).forEach(function (k, i) {
      var tr = el("tr", {"data-vertex": String(k.vertex), "data-time": String(k.raw)}, tb);
      if (k.problem) { tr.className = "bad"; tr.title = k.problem; tr.setAttribute("data-problem", k.problem); }
      el("td", {text: String(k.vertex)}, tr);
      var td = el("td", {}, tr), inp = el("input", {type: "text", inputmode: "decimal", value: String(k.raw),
        "aria-label": "time of keyframe " + i}, td);
      if (k.problem) el("span", {"class": "row-error", text: " " + k.problem}, td);
      inp.addEventListener("change", function () {
        self.remember();
        k.raw = inp.value;      // an empty box is a row without a time, never the old value
        self.interpolate();
      });
      var del = el("button", {type: "button", text: "x", title: "remove"}, el("td", {}, tr));
      del.addEventListener("click", function () {
        self.remember();
        self.st.keyframes.splice(i, 1);
        self.interpolate();
        self.listKeyframes();
      });
    });
    tb.setAttribute("data-count", String(this.st ? this.st.keyframes.length : 0));
    this.drawKeyframes();
  };
  Editor.prototype.drawKeyframes = function () {
    var g = this.kfGroup, V = this.V;
    if (!g) return;
    while (g.children.length) g.remove(g.children[0]);
    (this.st ? this.st.keyframes : []).forEach(function (k) {
      var m = new THREE.Mesh(new THREE.SphereGeometry(1.2, 16, 12),
        new THREE.MeshBasicMaterial({color: k.problem ? 0xcc0000 : 0x111111}));
      m.position.set(V[3 * k.vertex], V[3 * k.vertex + 1], V[3 * k.vertex + 2]);
      g.add(m);
    });
    this.render();
  };

  // ------------------------------------------------ preview: feasibility of the landscape
  Editor.prototype.previewSoon = function () {
    var self = this;
    if (this._soon) return;
    this._soon = setTimeout(function () { self._soon = null; self.preview(); }, 150);
  };
  Editor.prototype.preview = function () {
    if (this._soon) { clearTimeout(this._soon); this._soon = null; }
    // the landscape asked about already (a timer fired before the release): no second request
    if (this.previewed === this.version && this.previewedFor === this.st) return this.lastPreview;
    this.previewed = this.version; this.previewedFor = this.st;
    this.previewRequests = (this.previewRequests || 0) + 1;
    var self = this, seq = (this.seq = (this.seq || 0) + 1), t0 = performance.now();
    return (this.lastPreview = api("/api/build/" + this.build.id + "/preview", {landscape: Array.from(this.st.land)})
      .then(function (r) {
        if (seq !== self.seq) return;   // a newer edit is on its way
        setError("preview", null);
        self.feas = r.feasibility;
        self.paint();
        self.refreshHover();
        var f = $("feas");
        f.setAttribute("data-seq", String(seq));
        f.setAttribute("data-ms", String(Math.round(performance.now() - t0)));
      }).catch(function (e) { if (seq === self.seq) setError("preview", e.message); }));
  };

  // ------------------------------------------------ drawing
  var OUTLIER = [1.0, 0.5, 0.0];
  var BAND = {early: [0.85, 0.12, 0.1], late: [0.12, 0.3, 0.95], both: [0.6, 0.1, 0.7],
    ok: [0.2, 0.68, 0.32]};
  // the time scale: fixed (colours never shift under the brush) to the build's range, or
  // to the user's; a time beyond it is drawn orange and counted in the legend
  Editor.prototype.fixScale = function (range) {
    var land = range ? null : (this.buildLand || []), lo = Infinity, hi = -Infinity;
    if (range) { lo = range[0]; hi = range[1]; }
    else for (var i = 0; i < land.length; i++) { lo = Math.min(lo, land[i]); hi = Math.max(hi, land[i]); }
    if (!(hi - lo >= 1e-6)) { lo = (isFinite(lo) ? lo : 0) - 1; hi = lo + 2; }
    this.scale = {lo: lo, hi: hi, user: !!range};
    $("scale-lo").value = String(+lo.toPrecision(6)); $("scale-hi").value = String(+hi.toPrecision(6));
    $("scale-lo").classList.remove("bad"); $("scale-hi").classList.remove("bad");
    if (this.st) this.paint();
  };
  Editor.prototype.paint = function () {
    if (!this.mesh || !this.st) return;
    var land = this.st.land, feas = this.feas, i, beyond = 0;
    var slo = this.scale.lo, shi = this.scale.hi;
    var mode = $("colour-mode").value, col = this.mesh.geometry.getAttribute("color");
    for (i = 0; i < land.length; i++) {
      var c;
      if (mode === "diff") {
        c = this.diffColour(i);
      } else if (mode === "band" && feas) {
        var early = false, late = false;
        this.cellsOf[i].forEach(function (k) {
          if (feas.side[k] < 0) early = true; else if (feas.side[k] > 0) late = true;
        });
        c = early && late ? BAND.both : early ? BAND.early : late ? BAND.late : BAND.ok;
      } else if (land[i] < slo || land[i] > shi) {
        c = OUTLIER; beyond++;
      } else {
        c = MorphViewer.cmap("viridis", (land[i] - slo) / (shi - slo));
      }
      col.setXYZ(i, c[0], c[1], c[2]);
    }
    col.needsUpdate = true;
    this.container.setAttribute("data-colour", mode);
    if (feas) this.drawMarks(feas);
    this.beyond = mode === "band" ? 0 : beyond;
    this.container.setAttribute("data-beyond", String(this.beyond));
    this.drawLegend(mode, slo, shi);
    this.render();
  };
  // completion A - B of the compared builds at a vertex: the mean over its cells, on a
  // blue-white-red scale symmetric about 0 up to the 98th percentile of |A - B| (beyond it:
  // orange); grey where no cell has both times, or when nothing is compared
  Editor.prototype.diffColour = function (v) {
    var cmp = studio.compare, d = cmp && cmp.r.diff_done_s;
    if (!d || d.length !== this.target.vertex_a.length) return [0.55, 0.55, 0.55];
    if (!cmp.span) {
      var abs = d.filter(function (x) { return x !== null; }).map(Math.abs).sort(function (p, q) { return p - q; });
      cmp.span = abs.length ? Math.max(abs[Math.floor(0.98 * (abs.length - 1))], 1e-3) : 1;
    }
    var s = 0, n = 0;
    this.cellsOf[v].forEach(function (k) { if (d[k] !== null) { s += d[k]; n++; } });
    if (!n) return [0.55, 0.55, 0.55];
    var x = s / n;
    if (Math.abs(x) > cmp.span * (1 + 1e-9)) return OUTLIER;
    return MorphViewer.cmap("diverging", 0.5 + 0.5 * x / cmp.span);
  };
  Editor.prototype.drawMarks = function (feas) {
    var mid = this.target.mid, pts = [], cols = [], early = 0, late = 0, i;
    for (i = 0; i < feas.side.length; i++) {
      var s = feas.side[i];
      if (!s) continue;
      pts.push(mid[3 * i], mid[3 * i + 1], mid[3 * i + 2]);
      var c = s < 0 ? BAND.early : BAND.late;
      cols.push(c[0], c[1], c[2]);
      if (s < 0) early++; else late++;
    }
    var pg = this.marks.geometry;
    pg.setAttribute("position", new THREE.BufferAttribute(new Float32Array(pts), 3));
    pg.setAttribute("color", new THREE.BufferAttribute(new Float32Array(cols), 3));
    pg.computeBoundingSphere();
    var f = $("feas"), n = feas.side.length;
    var progN = this.target.programmed.clamped.reduce(function (a, b) { return a + b; }, 0);
    f.setAttribute("data-n-clamped", String(feas.n_clamped));
    f.setAttribute("data-programmed-clamped", String(progN));
    f.setAttribute("data-refused", feas.refused ? "1" : "0");
    f.textContent = feas.n_clamped + " of " + n + " cells cannot reach their time (" + early +
      " too early, " + late + " too late); " + (n - feas.n_clamped) + " within reach. Built " +
      "now: " + progN + " clamped." + (feas.refused ? " The program stage would refuse this " +
      "landscape: more than " + Math.round(100 * feas.max_clamped_fraction) + " % of the " +
      "cells cannot reach their time." : "");
    f.className = feas.refused ? "refused" : "";
  };
  Editor.prototype.drawLegend = function (mode, lo, hi) {
    var leg = $("legend-editor");
    leg.innerHTML = "";
    if (mode === "diff") {
      var cmp = studio.compare;
      leg.textContent = cmp ? "completion A - B (s): blue -" + fmt(cmp.span, 1) + ", white 0, red +" +
        fmt(cmp.span, 1) + " (98th percentile of |A - B|; orange beyond; grey: never completes)" :
        "completion A - B: compare two builds first (Results, Compare)";
      return;
    }
    if (mode === "band") {
      [["too early", BAND.early], ["too late", BAND.late], ["both", BAND.both], ["within reach", BAND.ok]]
        .forEach(function (p) {
          var sw = el("span", {"class": "swatch"}, leg);
          sw.style.background = "rgb(" + p[1].map(function (x) { return Math.round(255 * x); }).join(",") + ")";
          leg.appendChild(document.createTextNode(" " + p[0] + " "));
        });
      return;
    }
    var stops = [];
    for (var i = 0; i <= 10; i++) {
      var cc = MorphViewer.cmap("viridis", i / 10);
      stops.push("rgb(" + cc.map(function (x) { return Math.round(255 * x); }).join(",") + ") " + (10 * i) + "%");
    }
    leg.appendChild(document.createTextNode("requested time " + lo.toFixed(1) + " s "));
    var ramp = el("span", {"class": "mv-ramp"}, leg);
    ramp.style.background = "linear-gradient(90deg," + stops.join(",") + ")";
    leg.appendChild(document.createTextNode(" " + hi.toFixed(1) + " s" + (this.beyond ?
      " (orange: " + this.beyond + " vertices beyond the scale)" : "")));
  };

  // per-cell details of the cell nearest the pointer
  Editor.prototype.hover = function (x, y) {
    var tip = $("hover"), hit = this.hitPoint(x, y);
    if (!hit || !this.feas) { tip.style.display = "none"; return; }
    var mid = this.target.mid, best = -1, bd = Infinity, p = hit.point;
    for (var c = 0; c < mid.length / 3; c++) {
      var d = Math.hypot(mid[3 * c] - p.x, mid[3 * c + 1] - p.y, mid[3 * c + 2] - p.z);
      if (d < bd) { bd = d; best = c; }
    }
    if (best < 0) return;
    this.showCell(best, x, y);
  };
  Editor.prototype.showCell = function (c, x, y) {
    var tip = $("hover"), f = this.feas, pr = this.target.programmed;
    var side = f.side[c] < 0 ? "too early" : f.side[c] > 0 ? "too late" : "within reach";
    tip.innerHTML = "";
    el("b", {text: "cell " + c}, tip);
    el("div", {text: "requested t* " + fmt(f.t_star[c], 1) + " s: " + side + " (reachable " +
      fmt(f.t_min[c], 1) + "-" + fmt(f.t_max[c], 1) + " s)"}, tip);
    if (pr.t_sd && pr.t_sd[c] !== null) el("div", {text: "predicted sd of a print (bracket thickness scatter): " + fmt(pr.t_sd[c], 1) + " s"}, tip);
    el("div", {text: "as built: t* " + fmt(pr.t_star[c], 1) + " s, simulated completion " +
      (pr.t_done ? (pr.t_done[c] === null ? "never" : fmt(pr.t_done[c], 1) + " s") : "not simulated") +
      ", h top " + fmt(pr.h_top[c], 3) + " / bottom " + fmt(pr.h_bottom[c], 3) + " mm, " +
      (pr.clamped[c] ? "clamped" : "not clamped")}, tip);
    var r = this.canvas.getBoundingClientRect();
    tip.style.left = (x - r.left + 14) + "px"; tip.style.top = (y - r.top + 10) + "px";
    tip.style.display = "block";
    tip.setAttribute("data-cell", String(c));
    tip.setAttribute("data-version", String(this.version));
    this.hovered = {c: c, x: x, y: y};
  };
  // a tooltip still shown is drawn again with the new numbers (never stale after a stroke)
  Editor.prototype.refreshHover = function () {
    var h = this.hovered;
    if (h && $("hover").style.display === "block" && h.c < this.feas.side.length) this.showCell(h.c, h.x, h.y);
  };

  Editor.prototype.render = function () {
    this.renderer.render(this.scene, this.camera);
    this.container.setAttribute("data-renders", String((this.renders = (this.renders || 0) + 1)));
  };

  Editor.prototype.csv = function () {
    var lines = ["vertex_id,time_s"];
    this.st.land.forEach(function (t, i) { lines.push(i + "," + t); });
    return lines.join("\n") + "\n";
  };

  // ---------------------------------------------------------------- results and parts
  var FIGURES = [
    ["verdict", "verdict", null, 0],
    ["timing_rms_s", "timing RMS error, programmable cells (s)", -1, 2],
    ["timing_rms_all_s", "timing RMS error, all cells (s)", -1, 2],
    ["spearman", "Spearman (completion order)", 1, 3],
    ["n_clamped", "clamped cells", -1, 0],
    ["n_never_complete", "cells that never complete", -1, 0],
    ["shape_rms_mm", "final shape error, RMS (mm)", -1, 2],
    ["shape_rms_pct", "final shape error (% of size)", -1, 1],
    ["refine_rounds", "refinement rounds", null, 0],
  ];
  // the results of a build (default: the editor's); ``got``: its request, already sent
  function loadResults(build, got) {
    var b = build || studio.editor.build, box = $("results");
    return (got || api("/api/build/" + b.id + "/results")).then(function (r) {
      box.innerHTML = "";
      var link = $("report-link");
      link.hidden = !r.report;
      link.href = "/api/build/" + b.id + "/report";
      if (!r.now) { box.textContent = "no report in this build yet (press Run)"; box.setAttribute("data-state", "none"); return; }
      var v = el("div", {"class": "verdict " + r.now.verdict, text: r.now.verdict, id: "verdict"}, box);
      v.setAttribute("data-verdict", r.now.verdict);
      var ul = el("ul", {id: "reasons"}, box);
      (r.now.reasons || []).forEach(function (x) {
        el("li", {"class": x.level, text: x.level + " [" + x.check + "] " + x.message}, ul);
      });
      if (!(r.now.reasons || []).length) el("li", {text: "every check passed"}, ul);
      var tab = el("table", {id: "figures"}, box), head = el("tr", {}, tab);
      (r.before ? ["", "this build", "before this run (the build it was made from)", "change"] : ["", "this build"])
        .forEach(function (h) { el("th", {text: h}, head); });
      FIGURES.forEach(function (f) {
        var tr = el("tr", {"data-key": f[0]}, tab), now = r.now[f[0]], then = r.before ? r.before[f[0]] : undefined;
        el("td", {text: f[1]}, tr);
        el("td", {text: typeof now === "string" ? now : fmt(now, f[3])}, tr);
        if (!r.before) return;
        el("td", {text: typeof then === "string" ? then : fmt(then, f[3])}, tr);
        var td = el("td", {}, tr);
        if (f[2] !== null && isFinite(now) && isFinite(then) && now !== null && then !== null) {
          var dlt = now - then, same = Math.abs(dlt) < 0.5 * Math.pow(10, -f[3]);
          var better = dlt * f[2] > 0;
          td.textContent = same ? "no change" : (dlt > 0 ? "+" : "") + dlt.toFixed(f[3]) +
            (better ? " better" : " worse");
          td.className = same ? "" : better ? "better" : "worse";
        } else if (f[0] === "verdict" && now !== then) {
          td.textContent = then + " -> " + now;
        }
      });
      if (r.now.parts_fresh === false) el("p", {"class": "FAIL", text: "The STLs do not match the tables: do not print them."}, box);
      box.setAttribute("data-state", "shown");
      box.setAttribute("data-verdict", r.now.verdict);
    }).catch(function (e) { box.textContent = e.message; box.setAttribute("data-state", "error"); });
  }

  function loadParts(build) {
    var b = build || studio.editor.build, box = $("parts");
    return api("/api/build/" + b.id + "/parts").then(function (r) {
      box.innerHTML = "";
      if (!r.made_from.fresh) {
        el("p", {"class": "FAIL", text: "Not listed: " + r.made_from.problem + ". Press Run to make them again."}, box);
      } else if (!r.stls.length) {
        el("p", {text: "No STL in this build (it was built with --no-render)."}, box);
      }
      var tab = el("table", {id: "parts-table"}, box), head = el("tr", {}, tab);
      ["file", "size", "triangles", "what it is for", ""].forEach(function (h) { el("th", {text: h}, head); });
      r.stls.forEach(function (s) {
        var name = s.name.replace(/^stl\//, ""), tr = el("tr", {"data-name": name}, tab);
        el("td", {text: name}, tr);
        el("td", {text: (s.bytes / 1e6).toFixed(2) + " MB"}, tr);
        el("td", {text: String(s.triangles)}, tr);
        el("td", {text: s.purpose}, tr);
        var td = el("td", {}, tr);
        var show = el("button", {type: "button", text: "3D", "class": "part-3d"}, td);
        show.addEventListener("click", function () { previewPart(b, name); });
        var a = el("a", {href: "/api/build/" + b.id + "/stl/" + name, download: b.name + "-" + name,
          text: "download", "class": "part-download"}, td);
        a.setAttribute("data-name", name);
      });
      box.setAttribute("data-count", String(r.stls.length));
    }).catch(function (e) { box.textContent = e.message; });
  }

  function previewPart(b, name) {
    var box = $("part-view");
    box.textContent = "loading " + name + " ...";
    return fetch("/api/build/" + b.id + "/stl/" + name, {headers: headers(false)}).then(function (r) {
      if (!r.ok) return r.json().then(function (j) { throw new Error(j.error); });
      return r.arrayBuffer();
    }).then(function (buf) {
      box.innerHTML = "";
      el("div", {"class": "mv-title", text: name + " (drag to turn)"}, box);
      var pv = MorphViewer.partView(box, buf, {width: 520, height: 340});
      pv.render();
      box.setAttribute("data-part", name);
      box.setAttribute("data-triangles", String(pv.triangles));
      studio.partView = pv;
    }).catch(function (e) { box.textContent = name + ": " + e.message; });
  }

  // ---------------------------------------------------------------- run (a build again)
  // a Run names its build and the hash of the landscape the editor loaded for it (the server
  // refuses any other), and is sent from that build's own editing state
  function run() {
    var ed = studio.editor, st = ed.st;
    if (!st || (studio.loading !== null && studio.loading !== undefined)) return Promise.resolve();
    var variant = $("variant").checked ? $("variant-name").value.trim() : null;
    if (variant !== null && !/^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$/.test(variant)) {
      setError("run", "variant name \"" + variant + "\": use 1-64 letters, digits, - or _ (e.g. " +
        st.name + "-2)");
      return Promise.resolve();
    }
    setError("run", null);
    $("run").disabled = true;
    var sent = {id: st.id, name: st.name, land: Float64Array.from(st.land), edits: st.edits.length,
      variant: variant};
    return api("/api/build/" + st.id + "/run",
      {build: st.name, base_sha256: st.base, landscape: Array.from(st.land), edits: st.edits,
        variant: variant}).then(function (j) {
      studio.job = j;
      studio.sent = sent;
      ed.updateButtons();
      return poll();
    }).catch(function (e) {
      setError("run", "Run refused: " + e.message);
      ed.updateButtons();
    });
  }

  function eta(s) {
    if (s === null || s === undefined) return "";
    if (s < 60) return "about " + Math.max(1, Math.round(s)) + " s left";
    var m = Math.floor(s / 60), r = Math.round((s - 60 * m) / 10) * 10;
    if (r === 60) { m++; r = 0; }
    return "about " + m + " min " + (r ? r + " s " : "") + "left";
  }
  function poll() {
    return api("/api/job").then(function (j) {
      studio.job = j;
      var bar = $("progress"), text = $("progress-text");
      bar.value = j.progress;
      bar.setAttribute("data-value", String(j.progress));
      studio.editor.updateButtons();
      if (j.state === "running") {
        var k = j.plan ? j.plan.indexOf(j.stage) + 1 : 0;
        text.textContent = (j.stage ? j.stage + " (stage " + k + " of " + j.plan.length + ")" : "starting") +
          ", " + Math.round(100 * j.progress) + " %, " + eta(j.eta_s);
        text.setAttribute("data-state", "running");
        return new Promise(function (res) { setTimeout(res, 400); }).then(poll);
      }
      if (j.state === "error") {
        text.textContent = "the run failed";
        text.setAttribute("data-state", "error");
        setError("run", j.error);
        return;
      }
      if (j.state !== "done") return;
      text.textContent = "done in " + fmt(j.seconds, 0) + " s; reloading";
      return afterRun(j).then(function (where) {
        text.textContent = "done in " + fmt(j.seconds, 0) + " s";
        text.setAttribute("data-state", "done");
        Object.keys(errors).forEach(function (k) { errors[k] = null; });   // a run that worked
        showErrors();
        status(where, "done");
      });
    }).catch(function (e) { setError("run", e.message); });
  }

  // After a run: the builds again (a variant is listed after the others); an in-place run
  // reloads its build, keeping a pending draft as one undoable step on the new landscape;
  // a variant run leaves the original's state (and its undo history) as it was and opens
  // the variant.
  function afterRun(j) {
    var ed = studio.editor, sent = studio.sent || {id: j.build, variant: j.variant, edits: 0};
    return api("/api/builds").then(function (b) {
      studio.builds = b;
      fillSelector();
      var target = sent.variant ? b.filter(function (x) { return x.name === sent.variant; })[0] : b[sent.id];
      var old = ed.states[sent.id], state = null, kept = 0;
      if (!sent.variant) {
        kept = old && sent.land && old.id === sent.id ? ed.draftOf(old, sent) : 0;
        state = {land: kept ? Float64Array.from(old.land) : null, undo: [], redo: [],
          edits: kept ? old.edits.slice(sent.edits) : [], keyframes: []};
        ed.states[sent.id] = null;
      }
      studio.sent = null;
      $("edit-build").value = String(target.id);
      return ed.load(target, {keepCamera: !sent.variant}).then(function () {
        return Promise.all([loadViewers(), loadResults(), loadParts()]);
      }).then(function () {
        if (sent.variant) {   // did the edit work? the variant (A) against its original (B)
          $("variant").checked = false; $("variant-name").value = "";   // that name is taken now
          ed.updateButtons();
          $("cmp-a").value = String(target.id); $("cmp-b").value = String(sent.id);
          compare();
        }
        if (kept) {   // the draft on the new landscape, one undo step back to the built one
          ed.st.undo = [{land: Float64Array.from(ed.buildLand), edits: [], keyframes: []}];
          ed.st.land = state.land; ed.st.edits = state.edits;
          ed.changed(null);
        }
        return sent.variant ? "built into the new build " + sent.variant + " (" + sent.name +
          " is unchanged)" : "built again: see the results" +
          (kept ? "; the draft (" + kept + " vertices) is kept on the new landscape" : "");
      });
    });
  }
  // the cells with a vertex whose time differs from the build's own landscape
  Editor.prototype.paintedCells = function () {
    var st = this.st, seen = {}, out = [], self = this;
    for (var i = 0; i < st.land.length; i++) {
      if (st.land[i] === this.buildLand[i]) continue;
      this.cellsOf[i].forEach(function (c) { if (!seen[c]) { seen[c] = 1; out.push(c); } });
    }
    return out.sort(function (p, q) { return p - q; });
  };
  Editor.prototype.draftOf = function (st, sent) {
    var n = 0;
    for (var i = 0; i < st.land.length; i++) if (st.land[i] !== sent.land[i]) n++;
    return n;
  };
  function fillSelector() {
    var sel = $("edit-build"), keep = sel.value;
    sel.innerHTML = "";
    studio.builds.forEach(function (b) { el("option", {value: String(b.id), text: b.name}, sel); });
    if (keep) sel.value = keep;
    fillCompare();
    $("builds-note").textContent = studio.builds.map(function (b) { return b.path; }).join(" | ");
  }

  // ---------------------------------------------------------------- compare: A - B
  var REGION = [["requested_mean_s", "requested t*, mean (s)", 2], ["simulated_mean_s",
    "simulated completion, mean (s)", 2], ["timing_rms_s", "timing RMS, programmable cells (s)", 2],
    ["n_never_complete", "cells that never complete", 0], ["n_out_of_reach", "out of reach (clamped)", 0]];
  function compare() {
    var a = parseInt($("cmp-a").value, 10), b = parseInt($("cmp-b").value, 10), box = $("compare");
    var body = {other: b}, ed = studio.editor, painted = $("cmp-painted").checked;
    if (painted) {   // the region painted in the editor now (on the build it shows)
      body.cells = ed.paintedCells();
      if (!body.cells.length) {
        setError("compare", "compare: nothing is painted in the editor on " + ed.st.name +
          " (its landscape is the build's): paint there, or untick 'cells painted in the editor'");
        return Promise.resolve();
      }
    }
    var where = painted ? "painted in the editor on " + ed.st.name : "those whose requested time differs";
    box.setAttribute("data-state", "loading");
    return api("/api/build/" + a + "/compare", body).then(function (r) {
      setError("compare", null);
      studio.compare = {a: a, b: b, r: r};
      box.innerHTML = "";
      var na = "A: " + r.names.a, nb = "B: " + r.names.b;
      el("h4", {text: "The painted region: " + r.region.length + " cells (" + where + ")"}, box);
      var t = el("table", {id: "cmp-region"}, box), h = el("tr", {}, t);
      ["", na, nb, "A - B"].forEach(function (x) { el("th", {text: x}, h); });
      REGION.forEach(function (f) {
        var tr = el("tr", {"data-key": f[0]}, t), x = r.a[f[0]], y = r.b[f[0]];
        el("td", {text: f[1]}, tr); el("td", {text: fmt(x, f[2])}, tr); el("td", {text: fmt(y, f[2])}, tr);
        el("td", {text: (x === null || y === null) ? "n/a" : fmt(x - y, f[2])}, tr);
      });
      el("h4", {text: "Every figure of both builds"}, box);
      var t2 = el("table", {id: "cmp-figures"}, box), h2 = el("tr", {}, t2);
      ["", na, nb, "A - B"].forEach(function (x) { el("th", {text: x}, h2); });
      FIGURES.forEach(function (f) {
        var fa = r.figures.a || {}, fb = r.figures.b || {}, x = fa[f[0]], y = fb[f[0]];
        var tr = el("tr", {"data-key": f[0]}, t2);
        el("td", {text: f[1]}, tr);
        el("td", {text: typeof x === "string" ? x : fmt(x, f[3])}, tr);
        el("td", {text: typeof y === "string" ? y : fmt(y, f[3])}, tr);
        el("td", {text: typeof x === "number" && typeof y === "number" ? fmt(x - y, f[3]) : (x === y ? "same" : "")}, tr);
      });
      box.setAttribute("data-state", "shown");
      box.setAttribute("data-region", String(r.region.length));
      $("colour-mode").value = "diff";
      studio.editor.paint();
    }).catch(function (e) { setError("compare", "compare: " + e.message); box.setAttribute("data-state", "error"); });
  }
  function fillCompare() {
    ["cmp-a", "cmp-b"].forEach(function (id, k) {
      var sel = $(id), keep = sel.value;
      sel.innerHTML = "";
      studio.builds.forEach(function (b) { el("option", {value: String(b.id), text: b.name}, sel); });
      sel.value = keep || String(Math.min(k, studio.builds.length - 1));
    });
  }

  // a CSV file (vertex_id,time_s) as the landscape: checked by the server, one undoable step
  function importCsv(file) {
    var ed = studio.editor, st = ed.st;
    return file.text().then(function (text) {
      return api("/api/build/" + st.id + "/import", {csv: text});
    }).then(function (r) {
      if (ed.st !== st) return;
      setError("import", null);
      ed.remember();
      st.land = Float64Array.from(r.landscape);
      st.edits.push({tool: "import", mode: "csv"});
      ed.changed("landscape imported from " + file.name);
    }).catch(function (e) { setError("import", "import refused: " + e.message); });
  }
  studio.importCsv = importCsv;   // (tests: a File made in the page)

  // ---------------------------------------------------------------- start
  function init() {
    studio.token = net.token;
    var ed;
    studio.fields = {
      value: numberField("brush-value", "brush-error", {name: "value", changed: function () { ed && ed.brush(); },
        check: function (v) {
          var mode = $("brush-mode").value;
          if (v < 0) return (mode === "set" ? "time" : "seconds") + " must be 0 or more (a negative change is the subtract mode)";
          if (v > MAX_TIME) return (mode === "set" ? "time" : "seconds") + " " + v + " s is more than " + MAX_TIME + " s";
          return null;
        }}),
      radius: numberField("brush-radius", "brush-error", {name: "radius", changed: function () { ed && ed.brush(); },
        check: function (v) {
          if (v <= 0) return "radius must be more than 0 mm";
          if (v > MAX_RADIUS) return "radius " + v + " mm is more than " + MAX_RADIUS + " mm";
          return null;
        }}),
      falloff: numberField("brush-falloff", "brush-error", {name: "falloff", changed: function () { ed && ed.brush(); },
        check: function (v) { return v < 0 || v > 1 ? "falloff " + v + " is outside 0-1 (0 a hard edge, 1 smooth from the centre)" : null; }}),
      kfTime: numberField("kf-time", "kf-error", {name: "keyframe time", changed: function () {
        var r = studio.fields.kfTime.check();
        $("kf-error").textContent = r.ok ? "" : r.message;
      }, check: function (v) { return v < 0 || v > MAX_TIME ? "time " + v + " s is outside 0-" + MAX_TIME + " s" : null; }}),
    };
    $("brush-mode").addEventListener("change", function () {
      var m = $("brush-mode").value;
      $("brush-value").disabled = m === "smooth";
      $("brush-value-label").textContent = m === "set" ? "time" : m === "smooth" ? "(no value)" : "seconds";
      ed && ed.brush();
    });
    // the session cookie (for downloads), the builds and the first build's data were asked
    // for at once by boot.js: every api call carries the token in its header, so nothing
    // waits for the cookie
    var first = net.first;
    first.builds.then(function (builds) {
      studio.builds = builds;
      var sel = $("edit-build");
      fillSelector();
      ed = studio.editor = new Editor($("editor-view"));
      sel.addEventListener("change", function () {
        var b = studio.builds[parseInt(sel.value, 10)];
        ed.load(b).then(function () { return Promise.all([loadResults(), loadParts()]); });
      });
      $("variant").addEventListener("change", function () {
        if ($("variant").checked && !$("variant-name").value) {
          var names = studio.builds.map(function (b) { return b.name; }), k = 2;
          while (names.indexOf(ed.st.name + "-" + k) >= 0) k++;
          $("variant-name").value = ed.st.name + "-" + k;
        }
        ed.updateButtons();
      });
      $("import").addEventListener("click", function () { $("import-file").click(); });
      $("import-file").addEventListener("change", function () {
        var f = $("import-file").files[0];
        if (f) importCsv(f);
        $("import-file").value = "";
      });
      $("undo").addEventListener("click", function () { ed.undo(); });
      $("redo").addEventListener("click", function () { ed.redo(); });
      $("reset").addEventListener("click", function () { ed.reset(); });
      $("colour-mode").addEventListener("change", function () { ed.paint(); });
      ["scale-lo", "scale-hi"].forEach(function (id) {
        $(id).addEventListener("change", function () {
          var lo = parseFloat($("scale-lo").value), hi = parseFloat($("scale-hi").value);
          var ok = isFinite(lo) && isFinite(hi) && hi > lo;
          $("scale-lo").classList.toggle("bad", !ok); $("scale-hi").classList.toggle("bad", !ok);
          if (ok) ed.fixScale([lo, hi]);     // a bad pair is marked, never replaced
        });
      });
      $("scale-build").addEventListener("click", function () { ed.fixScale(null); });
      $("cmp-go").addEventListener("click", compare);
      ["top", "side", "reset"].forEach(function (n) {
        $("view-" + n).addEventListener("click", function () { ed.orbit.preset(n, function () { ed.fit(); }); });
      });
      $("download").addEventListener("click", function () {
        var a = el("a", {href: URL.createObjectURL(new Blob([ed.csv()], {type: "text/csv"})),
          download: ed.build.name + "-time_landscape.csv"});
        a.click();
      });
      document.querySelectorAll("input[name=tool]").forEach(function (r) {
        r.addEventListener("change", function () {
          $("brush-box").disabled = ed.tool() !== "brush";
          $("kf-box").disabled = ed.tool() !== "keyframe";
        });
      });
      $("kf-box").disabled = true;
      document.addEventListener("keydown", function (e) {
        if (!(e.ctrlKey || e.metaKey) || e.target.tagName === "INPUT") return;
        if (e.key === "z" && !e.shiftKey) { e.preventDefault(); ed.undo(); }
        if (e.key === "y" || (e.key === "z" && e.shiftKey)) { e.preventDefault(); ed.redo(); }
      });
      window.addEventListener("beforeunload", function (e) {
        if (ed.dirty() && !(studio.job && studio.job.state === "running")) { e.preventDefault(); e.returnValue = ""; }
      });
      $("run").addEventListener("click", run);
      // the editor (target, landscape, feasibility), the results and the job at once
      // (small): the page is usable then; the parts and the morph viewer's data (megabytes,
      // gzip-compressed, made by the server while the editor loaded) come after
      return Promise.all([ed.load(builds[0], {target: first.target}),
        loadResults(builds[0], first.results), first.job.then(function (j) {
        studio.job = j;
        if (j.state === "running") poll();   // a run started before a reload: follow it
      })]).then(function () {
        document.body.setAttribute("data-usable", String(Math.round(performance.now())));
        $("viewers").textContent = "loading the morph viewer ...";
        return Promise.all([loadParts(), loadViewers(), first.session]);   // (downloads: the cookie)
      });
    }).then(function () {
      document.body.setAttribute("data-ready-ms", String(Math.round(performance.now())));
      document.body.setAttribute("data-ready", "1");
    }).catch(function (e) {
      if (e.status === 403) $("token-missing").hidden = false;   // neither cookie nor token
      setError("load", e.message);
      document.body.setAttribute("data-ready", "error");
    });
  }
  init();
})();
