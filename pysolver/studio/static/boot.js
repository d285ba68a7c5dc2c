/* morphshell studio: the page's network side, loaded first (in the head, before three.js and
 * the app), so that the first requests go out while those load and the server answers them
 * meanwhile.  Talks only to the local server that served this page (same origin, JSON).  Its
 * token is in the session cookie the private page the studio opened obtained (POST /session,
 * no URL); on the printed URL's #token=..., it is dropped from the address bar at once,
 * exchanged for that cookie too, and sent in a header.  studio.js reads window.studioNet. */
(function () {
  "use strict";

  // On the printed URL the token arrives after # (never sent to a server); it is kept in this tab's
  // sessionStorage (a reload keeps working) and dropped from the address bar and the
  // history entry at once, so it is not left in the browser's history.
  function tokenFromUrl() {
    var m = /(?:^|[#&])token=([A-Za-z0-9_\-]+)/.exec(location.hash || "");
    var token = m ? m[1] : null;
    try {
      if (token) sessionStorage.setItem("morphshell-token", token);
      else token = sessionStorage.getItem("morphshell-token");
    } catch (e) { /* storage disabled: the token lives in this page only */ }
    if (m) history.replaceState(null, "", location.pathname + location.search);
    return token;
  }
  var token = tokenFromUrl();
  function headers(json) {
    var h = token ? {"X-Morphshell-Token": token} : {};
    if (json) h["Content-Type"] = "application/json";
    return h;
  }
  // a JSON call; a refusal rejects with the server's message, its fix and its status
  function api(path, body) {
    var opt = body === undefined ? {headers: headers(false)} :
      {method: "POST", body: JSON.stringify(body), headers: headers(true)};
    return fetch(path, opt).then(reply);
  }
  function reply(r) {
    return r.json().then(function (j) {
      if (!r.ok) {
        var e = new Error((j.error || ("HTTP " + r.status)) + (j.fix ? " (fix: " + j.fix + ")" : ""));
        e.status = r.status;
        throw e;
      }
      return j;
    });
  }
  // a large JSON GET read as it arrives: onBytes(received, total) after each piece (total:
  // the JSON's bytes, X-Morphshell-Bytes, since the body arrives decompressed; 0 unknown)
  function apiRead(path, onBytes) {
    return fetch(path, {headers: headers(false)}).then(function (r) {
      if (!r.ok || !r.body || !window.TextDecoder) return reply(r);
      var total = +r.headers.get("X-Morphshell-Bytes") || 0, got = 0, pieces = [];
      var reader = r.body.getReader();
      function next() {
        return reader.read().then(function (x) {
          if (!x.done) {
            pieces.push(x.value);
            got += x.value.length;
            onBytes(got, total);
            return next();
          }
          var all = new Uint8Array(got), k = 0;
          pieces.forEach(function (p) { all.set(p, k); k += p.length; });
          return JSON.parse(new TextDecoder().decode(all));
        });
      }
      return next();
    });
  }
  // the token as the session cookie (downloads need no token in their URL)
  function session() {
    if (!token) return Promise.resolve();
    return fetch("/session", {method: "POST", body: "token=" + encodeURIComponent(token),
      headers: {"Content-Type": "application/x-www-form-urlencoded"}}).then(function () {});
  }
  // what the page needs first, all at once: the builds, and the first build's (every studio
  // has one) target, results and the job; studio.js takes them (their errors too: until
  // then a refusal is not reported as unhandled)
  var first = {session: session(), builds: api("/api/builds"), target: api("/api/build/0/target"),
    results: api("/api/build/0/results"), job: api("/api/job")};
  Object.keys(first).forEach(function (k) { first[k].catch(function () {}); });
  window.studioNet = {token: token, headers: headers, api: api, apiRead: apiRead, first: first};
})();
