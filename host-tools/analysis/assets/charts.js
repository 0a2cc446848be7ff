// Charts of the pages needle writes (`needle diagnose --report`, `needle
// fit --plot`) from the descriptions the page carries (NEEDLE_CHARTS), and
// what the live view shares with them. Plots are uPlot (bundled, MIT).
"use strict";

// Lines in the points' own order (a needle goes in and comes out: x is
// not sorted), for uPlot's x-y mode.
function inOrder(u, seriesIdx) {
  const [xs, ys] = u.data[seriesIdx];
  const stroke = new Path2D();
  const sx = u.series[seriesIdx].facets[0].scale, sy = u.series[seriesIdx].facets[1].scale;
  for (let i = 0; i < xs.length; i++) {
    const px = u.valToPos(xs[i], sx, true), py = u.valToPos(ys[i], sy, true);
    if (i === 0) stroke.moveTo(px, py); else stroke.lineTo(px, py);
  }
  return { stroke, fill: null, clip: null, band: null, gaps: null, flags: 0 };
}

function chartWidth() {
  return Math.max(400, Math.min(1200, document.body.clientWidth - 40));
}

// A label beside a vertical position, on the side with room for it.
function labelAt(u, x, y, text) {
  const right = x > u.bbox.left + 0.7 * u.bbox.width;
  u.ctx.textAlign = right ? "right" : "left";
  u.ctx.fillText(text, right ? x - 4 : x + 4, y);
}

// One static chart: {caption, x_label, y_label, lines: [{label, colour,
// dashed, x, y}], markers: [{label, x, y}], bands: [{from, to, label,
// colour}]}, into `element`.
function drawChart(chart, element) {
  const series = [{}];
  for (const line of chart.lines) {
    series.push({
      label: line.label, stroke: line.colour, width: 1.5, dash: line.dashed ? [6, 4] : undefined,
      paths: inOrder, points: { show: false }, facets: [{ scale: "x", auto: true }, { scale: "y", auto: true }],
    });
  }
  const shade = u => {
    const ctx = u.ctx;
    for (const b of chart.bands) {
      const x0 = u.valToPos(b.from, "x", true), x1 = u.valToPos(b.to, "x", true);
      ctx.fillStyle = b.colour;
      ctx.fillRect(x0, u.bbox.top, Math.max(1, x1 - x0), u.bbox.height);
    }
  };
  const mark = u => {
    const ctx = u.ctx;
    ctx.save();
    ctx.font = `${12 * devicePixelRatio}px sans-serif`;
    ctx.fillStyle = "#000";
    for (const m of chart.markers) {
      const x = u.valToPos(m.x, "x", true), y = u.valToPos(m.y, "y", true);
      ctx.beginPath();
      ctx.arc(x, y, 4 * devicePixelRatio, 0, 2 * Math.PI);
      ctx.fill();
      labelAt(u, x, y - 8 * devicePixelRatio, m.label);
    }
    // Each phase named once, at the top of its first band wide enough
    // to hold the name.
    const named = new Set();
    ctx.fillStyle = "#555";
    for (const b of chart.bands) {
      const x0 = u.valToPos(b.from, "x", true), x1 = u.valToPos(b.to, "x", true);
      if (named.has(b.label) || x1 - x0 < ctx.measureText(b.label).width + 8) continue;
      named.add(b.label);
      ctx.textAlign = "left";
      ctx.fillText(b.label, x0 + 4, u.bbox.top + 14 * devicePixelRatio);
    }
    ctx.restore();
  };
  new uPlot({
    mode: 2, width: chartWidth(), height: chart.height,
    scales: { x: { time: false, auto: true }, y: { auto: true } },
    axes: [{ label: chart.x_label }, { label: chart.y_label }],
    legend: { live: false },
    series,
    hooks: { drawClear: [shade], draw: [mark] },
  }, [null, ...chart.lines.map(l => [l.x, l.y])], element);
}

if (typeof NEEDLE_CHARTS !== "undefined") {
  NEEDLE_CHARTS.forEach((chart, i) => drawChart(chart, document.getElementById(`chart-${i}`)));
}
