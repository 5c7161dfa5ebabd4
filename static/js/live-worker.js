// Live page worker: receives, decodes and draws the depth panels off the main thread
// (see live-stream.js). The page transfers one OffscreenCanvas per sensor.
"use strict";
importScripts("/js/live-stream.js");

const canvases = {};
let stream = null;

self.onmessage = (ev) => {
  const m = ev.data;
  if (m.type === "start" && !stream) {
    // eslint-disable-next-line no-undef
    stream = gaitrigLiveStream({ url: m.url, canvas: (node) => canvases[node] || null,
      report: (msg) => self.postMessage(msg),
      // a panel whose caption changes: drawn by the page with it (live-stream.js)
      handover: (node, bitmap, tracked) => self.postMessage({ type: "handover", node, bitmap, tracked }, [bitmap]) });
  } else if (m.type === "captioned") {
    if (stream) stream.captioned(m.node, m.tracked);
  } else if (m.type === "canvas") {
    canvases[m.node] = m.canvas;
    if (stream) stream.canvasReady(m.node);
  }
};
