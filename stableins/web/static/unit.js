// Draws each parameter's trend on the unit page: the data-only estimates with their ±1σ band, the values the
// records state, and the fitted drift line (the numbers of /api/units/SERIAL, embedded in the page).
(function () {
  "use strict";
  function draw() {
    var source = document.getElementById("trend-data");
    if (!source || typeof Plotly === "undefined") return;
    var trends = JSON.parse(source.textContent);
    trends.forEach(function (t, k) {
      var box = document.querySelector("#trend-" + k + " .plot");
      if (!box) return;
      var upper = t.values.map(function (v, i) { return v + t.sigmas[i]; });
      var lower = t.values.map(function (v, i) { return v - t.sigmas[i]; });
      var traces = [
        { x: t.times, y: upper, mode: "lines", line: { width: 0 }, hoverinfo: "skip", showlegend: false },
        { x: t.times, y: lower, mode: "lines", line: { width: 0 }, fill: "tonexty", fillcolor: "rgba(31,95,168,0.18)",
          name: "±1σ (its data alone)", hoverinfo: "skip" },
        { x: t.times, y: t.values, mode: "markers", marker: { size: 7, color: "#1f5fa8" }, name: "its data alone",
          error_y: { type: "data", array: t.sigmas, visible: true, thickness: 1 } }
      ];
      if (t.record_values.length) {
        traces.push({ x: t.times, y: t.record_values, mode: "markers", marker: { size: 6, symbol: "diamond-open", color: "#444" },
          name: "record states" });
      }
      if (t.line.length) {
        traces.push({ x: t.times, y: t.line, mode: "lines", line: { color: Math.abs(t.significance) >= 3 ? "#b42318" : "#157f3b" },
          name: "drift, z = " + t.significance.toFixed(2) });
      }
      Plotly.newPlot(box, traces, {
        title: { text: t.id + " [" + t.unit + "]", font: { size: 13 } },
        margin: { l: 60, r: 10, t: 32, b: 40 }, legend: { orientation: "h", y: -0.25, font: { size: 10 } },
        xaxis: { type: "date" }, yaxis: { zeroline: false }
      }, { displayModeBar: false, responsive: true });
      box.setAttribute("data-drawn", "true");
    });
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", draw); else draw();
})();
