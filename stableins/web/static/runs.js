// The runs page: rows rebuilt from the server-sent events of /api/runs/events (the journals' progress as it grows).
(function () {
  "use strict";
  function text(v) { return v === null || v === undefined ? "—" : String(v); }
  function duration(s) {
    if (s === null || s === undefined) return "—";
    s = Math.max(0, Math.round(s));
    var h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), r = s % 60;
    return (h ? h + " h " : "") + (h || m ? m + " min " : "") + r + " s";
  }
  function cell(row, value, cls) { var td = document.createElement("td"); td.textContent = value; if (cls) td.className = cls; row.appendChild(td); }
  function render(data) {
    var body = document.getElementById("runs-body");
    var looks = document.getElementById("quicklooks");
    body.textContent = "";
    looks.textContent = "";
    if (!data.runs.length) { var tr = document.createElement("tr"); cell(tr, "no runs under the run root"); body.appendChild(tr); }
    data.runs.forEach(function (r) {
      var tr = document.createElement("tr");
      tr.setAttribute("data-run", r.name);
      tr.className = "state-" + r.state;
      cell(tr, r.name); cell(tr, r.unit); cell(tr, r.procedure);
      cell(tr, r.state + (r.reason ? ": " + r.reason : ""));
      cell(tr, text(r.step) + "/" + r.steps + (r.step_name ? " " + r.step_name : ""));
      cell(tr, text(r.stage) + (r.phase ? " (" + r.phase + ")" : ""));
      cell(tr, r.position ? r.position + (r.pass ? " (pass " + r.pass + ")" : "") : "—");
      cell(tr, r.state === "running" ? Math.round(r.dwell_seconds) + " s (plan " + Math.round(r.dwell_planned) + " s)" : "—");
      cell(tr, String(r.samples), "samples num");
      cell(tr, (r.remaining_is_lower_bound ? "≥ " : "") + duration(r.remaining_seconds));
      cell(tr, String(r.journal_records), "records num");
      body.appendChild(tr);
      if (r.quicklook) {
        var div = document.createElement("div");
        div.className = "quicklook";
        div.setAttribute("data-run", r.name);
        var h = document.createElement("b"); h.textContent = r.name + " — quick look: "; div.appendChild(h);
        div.appendChild(document.createTextNode(r.quicklook.text));
        looks.appendChild(div);
      }
    });
    document.body.setAttribute("data-updated", String(Date.now()));
  }
  function start() {
    var initial = document.getElementById("initial-runs");
    if (initial) render(JSON.parse(initial.textContent));
    var live = document.getElementById("live");
    if (typeof EventSource === "undefined") { live.textContent = "no live updates in this browser: reload"; return; }
    var source = new EventSource("/api/runs/events");
    source.addEventListener("runs", function (event) { render(JSON.parse(event.data)); live.textContent = "live"; });
    source.onerror = function () { live.textContent = "reconnecting…"; };
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start); else start();
})();
