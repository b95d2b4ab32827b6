// Browsers that watch the operator page (hng bench loop --browsers N): N headless Chromium
// instances (each its own browser process and profile), each with the page open, driven by
// playwright-core. Prints {"event":"watching", ...} once every page is connected to the live
// stream (the bench then publishes its scans; the scan frames each page received are counted),
// then keeps them open until a line arrives on stdin (or stdin closes), prints
// {"event":"done", "scans": [frames each page received]} and closes them.
//
// node watch.mjs URL N
import { chromium } from "playwright-core";
import fs from "node:fs";
import os from "node:os";
import path from "node:path";

const [url, nArg] = process.argv.slice(2);
const n = Number(nArg || 3);
const say = (o) => process.stdout.write(JSON.stringify(o) + "\n");
const browsers = [], pages = [], dirs = [];
let code = 0;
try {
  for (let i = 0; i < n; i++) {
    const dir = fs.mkdtempSync(path.join(os.tmpdir(), "hng-watch-"));
    dirs.push(dir);
    const b = await chromium.launchPersistentContext(dir, {
      executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
      headless: true,
      viewport: { width: 1500, height: 950 },
      args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"],
    });
    browsers.push(b);
    const page = b.pages()[0] || (await b.newPage());
    await page.goto(url);
    pages.push(page);
  }
  for (const p of pages) {
    await p.waitForFunction(() => (window.hng.state.counts.hello || 0) >= 1, null, { timeout: 60000 });
  }
  const counts = async () => Promise.all(pages.map((p) => p.evaluate(() => window.hng.state.counts.scan || 0)));
  say({ event: "watching", scans: await counts() });
  await new Promise((resolve) => {
    process.stdin.on("data", resolve);
    process.stdin.on("end", resolve);
  });
  say({ event: "done", scans: await counts() });
} catch (e) {
  say({ event: "error", error: String(e && e.stack || e) });
  code = 1;
} finally {
  for (const b of browsers) await b.close().catch(() => {});
  for (const d of dirs) fs.rmSync(d, { recursive: true, force: true });
}
process.exit(code);
