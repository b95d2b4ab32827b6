// Designation by clicking in the camera image, in a real browser (tests/system/gui.rs):
// headless Chromium driven by playwright-core. One JSON object per line ({"event": ...}).
//
// node designate.mjs URL ARTEFACT_DIR HIT_FRACTION MISS_FRACTION [BEACONS]
//   - loads the page; waits until an image has come and BEACONS (default 2) beacons are
//     tracked;
//   - clicks the camera image at HIT_FRACTION of its width (half its height), reports the
//     page's answer, saves gui-camera.png;
//   - clicks at MISS_FRACTION, reports the answer text.
// The test computes the fractions from the bearings and the field of view it published; the
// page must turn the click back into a bearing with that field of view.
import { say, withPage } from "./launch.mjs";
import path from "node:path";

const [url, dir, hitArg, missArg, beaconsArg] = process.argv.slice(2);
const beacons = Number(beaconsArg || 2);
await withPage(url, dir, async (page) => {
  await page.waitForFunction((n) => (window.hng.state.counts.image || 0) >= 1 && window.hng.seenBeacons().length >= n, beacons, { timeout: 60000 });
  say({ event: "tracked", beacons: await page.evaluate(() => window.hng.seenBeacons()), hfov: await page.evaluate(() => window.hng.state.image.hfov) });
  const click = async (fraction) => {
    const r = await page.evaluate(() => { const b = document.getElementById("camera").getBoundingClientRect(); return { x: b.left, y: b.top, w: b.width, h: b.height }; });
    await page.mouse.click(r.x + fraction * r.w, r.y + r.h / 2);
  };
  await click(Number(hitArg));
  await page.waitForFunction(() => window.hng.state.answers.length > 0, null, { timeout: 10000 });
  say({ event: "hit", answer: await page.evaluate(() => window.hng.state.answers[0]), text: await page.textContent("#answer") });
  await page.waitForTimeout(300); // the panels' next drawing, for the screenshot
  await page.screenshot({ path: path.join(dir, "gui-camera.png") });
  await click(Number(missArg));
  await page.waitForFunction(() => document.getElementById("answer").textContent.startsWith("no beacon there"), null, { timeout: 10000 });
  say({ event: "miss", answers: await page.evaluate(() => window.hng.state.answers.length), text: await page.textContent("#answer") });
});
