// Load a rerun web viewer in headless Chromium, wait until the recording is drawn, screenshot it.
//
// usage: node screenshot.mjs URL OUT.png [--timeout-s 90] [--width 1600] [--height 900]
//                            [--chromium /usr/bin/chromium] [--settle-s 3] [--seek-frac F]
//
// "Drawn" is decided from the pixels, not from a fixed sleep: every second the page is captured,
// the capture is decoded inside the page (createImageBitmap on a 2D OffscreenCanvas) and the pixels
// close to the view's own colours are counted: the truth axes' red (220, 40, 40) and green
// (30, 170, 50) and the gyro's blue series (80, 130, 255). The rerun welcome screen has none of
// them. Once all are present and the count has stopped changing between two captures (the
// viewer has finished loading and laying out), a last screenshot is written to OUT.png and a
// JSON line with the pixel statistics is printed on stdout. Exit code 0 on success, 1 on timeout
// (with the last capture still written to OUT.png for diagnosis), 2 on bad usage.
//
// --seek-frac F (for README pictures, not used by the test): once drawn, click the time panel's
// slider at the fraction F of its length (the slider is found as the longest dark horizontal run
// in the bottom 40 pixel rows), pause the playback if it runs (its button is blue while playing)
// and wait for the pixels to settle again before the screenshot.

import { chromium } from "playwright-core";
import fs from "node:fs";
import os from "node:os";
import path from "node:path";

function parseArgs(argv) {
  const opts = {
    timeoutS: 90,
    width: 1600,
    height: 900,
    chromium: "/usr/bin/chromium",
    settleS: 3,
    seekFrac: null,
  };
  const pos = [];
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => argv[++i];
    if (a === "--timeout-s") opts.timeoutS = Number(next());
    else if (a === "--width") opts.width = Number(next());
    else if (a === "--height") opts.height = Number(next());
    else if (a === "--chromium") opts.chromium = next();
    else if (a === "--settle-s") opts.settleS = Number(next());
    else if (a === "--seek-frac") opts.seekFrac = Number(next());
    else pos.push(a);
  }
  if (pos.length !== 2) {
    console.error("usage: node screenshot.mjs URL OUT.png [--timeout-s S] [--width W] [--height H]");
    process.exit(2);
  }
  return { url: pos[0], out: pos[1], ...opts };
}

// Runs in the page: decode a PNG (base64) and count pixels near each target colour.
async function pixelStats({ pngBase64, targets }) {
  const blob = await (await fetch(`data:image/png;base64,${pngBase64}`)).blob();
  const bmp = await createImageBitmap(blob);
  const canvas = new OffscreenCanvas(bmp.width, bmp.height);
  const ctx = canvas.getContext("2d");
  ctx.drawImage(bmp, 0, 0);
  const d = ctx.getImageData(0, 0, bmp.width, bmp.height).data;
  const counts = targets.map(() => 0);
  let sum = 0;
  let sum2 = 0;
  const n = d.length / 4;
  for (let i = 0; i < d.length; i += 4) {
    const r = d[i], g = d[i + 1], b = d[i + 2];
    const y = 0.299 * r + 0.587 * g + 0.114 * b;
    sum += y;
    sum2 += y * y;
    for (let k = 0; k < targets.length; k++) {
      const t = targets[k];
      if (Math.abs(r - t[0]) < 40 && Math.abs(g - t[1]) < 40 && Math.abs(b - t[2]) < 40) counts[k]++;
    }
  }
  const mean = sum / n;
  // The time slider: the longest run of dark pixels in the bottom 40 rows.
  let slider = { y: 0, x0: 0, x1: 0 };
  for (let y = bmp.height - 40; y < bmp.height; y++) {
    let start = -1;
    for (let x = 0; x <= bmp.width; x++) {
      const i = 4 * (y * bmp.width + x);
      const dark = x < bmp.width && 0.299 * d[i] + 0.587 * d[i + 1] + 0.114 * d[i + 2] < 110;
      if (dark && start < 0) start = x;
      if (!dark && start >= 0) {
        if (x - start > slider.x1 - slider.x0) slider = { y, x0: start, x1: x };
        start = -1;
      }
    }
  }
  // The play/pause button (bottom-left) is drawn on a blue square while playing.
  let play = { n: 0, x: 0, y: 0 };
  for (let y = bmp.height - 30; y < bmp.height; y++) {
    for (let x = 0; x < 60; x++) {
      const i = 4 * (y * bmp.width + x);
      if (d[i + 2] > 180 && d[i] < 120 && d[i + 2] - d[i + 1] > 60) {
        play = { n: play.n + 1, x: play.x + x, y: play.y + y };
      }
    }
  }
  const playing = play.n > 20 ? { x: play.x / play.n, y: play.y / play.n } : null;
  return {
    width: bmp.width,
    height: bmp.height,
    counts,
    lumaStd: Math.sqrt(sum2 / n - mean * mean),
    slider,
    playing,
  };
}

const TARGETS = [
  [220, 40, 40], // truth x axis
  [30, 170, 50], // truth y axis
  [80, 130, 255], // gyro ω_z series
];
const MIN_PIXELS = 30;

async function main() {
  const o = parseArgs(process.argv.slice(2));
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), "imu-dcm-chromium-"));
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: o.chromium,
    headless: true,
    viewport: { width: o.width, height: o.height },
    args: [
      "--headless",
      "--no-sandbox",
      "--disable-gpu",
      "--disable-quic",
      "--no-first-run",
      "--disable-background-networking",
      "--disable-component-update",
      "--disable-sync",
      // WebGL on the CPU (SwiftShader): the viewer needs WebGL2 or WebGPU and there is no GPU.
      "--use-angle=swiftshader",
      "--enable-unsafe-swiftshader",
    ],
  });
  let ok = false;
  let last = null;
  const t0 = Date.now();
  try {
    const page = context.pages()[0] ?? (await context.newPage());
    const seen = new Set();
    page.on("console", (m) => {
      const line = m.text().split("\n")[0];
      if (m.type() === "error" && !seen.has(line)) {
        seen.add(line); // each distinct page error once, first line only
        console.error(`[page] ${line}`);
      }
    });
    await page.goto(o.url, { waitUntil: "load", timeout: o.timeoutS * 1000 });
    await page.waitForSelector("canvas", { timeout: o.timeoutS * 1000 });
    let prev = null;
    let stableSince = null;
    let seeked = false;
    while ((Date.now() - t0) / 1000 < o.timeoutS) {
      const png = await page.screenshot({ type: "png" });
      last = png;
      const stats = await page.evaluate(pixelStats, {
        pngBase64: png.toString("base64"),
        targets: TARGETS,
      });
      stats.elapsedS = (Date.now() - t0) / 1000;
      if (process.env.SCREENSHOT_DEBUG) console.error(JSON.stringify(stats));
      // Before a seek only the plots must be in (the truth may be absent at the log's end).
      const needed = o.seekFrac !== null ? stats.counts.slice(2) : stats.counts;
      const drawn = needed.every((c) => c >= MIN_PIXELS);
      const same = prev && prev.counts.every((c, k) => Math.abs(c - stats.counts[k]) <= 0.02 * c + 5);
      if (drawn && same) {
        stableSince ??= Date.now();
        if (o.seekFrac !== null && (Date.now() - stableSince) / 1000 >= o.settleS) {
          const { y, x0, x1 } = stats.slider;
          await page.mouse.click(x0 + o.seekFrac * (x1 - x0), y);
          o.seekFrac = null; // once; then settle again
          seeked = true;
          stableSince = null;
          prev = null;
          await page.waitForTimeout(1000);
          continue;
        }
        if ((Date.now() - stableSince) / 1000 >= o.settleS) {
          fs.writeFileSync(o.out, png);
          console.log(JSON.stringify({ ok: true, ...stats }));
          ok = true;
          break;
        }
      } else {
        stableSince = null;
        // After the seek the playback may run on: pause it with its button.
        if (seeked && stats.playing) {
          await page.mouse.click(stats.playing.x, stats.playing.y);
        }
      }
      prev = stats;
      await page.waitForTimeout(1000);
    }
    if (!ok) {
      if (last) fs.writeFileSync(o.out, last);
      console.log(JSON.stringify({ ok: false, reason: "timeout", ...(prev ?? {}) }));
    }
  } finally {
    await context.close();
    fs.rmSync(userDataDir, { recursive: true, force: true });
  }
  process.exit(ok ? 0 : 1);
}

main().catch((e) => {
  console.error(String(e && e.stack ? e.stack : e));
  process.exit(1);
});
