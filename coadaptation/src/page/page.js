// The operator page's only script: every few seconds it fetches the live part and the
// prototype panel again and swaps them in. The panel is replaced only when what it asks
// changed (its data-key), so measured dimensions being typed are never wiped. Without
// script the page still works: reload it by hand.
"use strict";
(function () {
  const every = 3000;
  async function fragment(path) {
    const r = await fetch(path, { credentials: "same-origin", cache: "no-store" });
    if (r.status === 401 || r.status === 403) {
      // The session ended (the server restarted, or it expired): show the login again.
      location.reload();
      return null;
    }
    return r.ok ? r.text() : null;
  }
  async function tick() {
    try {
      const live = await fragment("/live");
      const el = document.getElementById("live");
      if (live !== null && el) el.innerHTML = live;
      const panel = await fragment("/panel");
      const old = document.getElementById("prototype");
      if (panel !== null && old) {
        const t = document.createElement("template");
        t.innerHTML = panel;
        const fresh = t.content.firstElementChild;
        if (fresh && fresh.dataset.key !== old.dataset.key) old.replaceWith(fresh);
      }
      document.body.classList.remove("offline");
    } catch (e) {
      // The learner is unreachable (stopped, or the network): say so, keep trying.
      document.body.classList.add("offline");
    }
    setTimeout(tick, every);
  }
  if (document.getElementById("live")) setTimeout(tick, every);
})();
