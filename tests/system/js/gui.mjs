// The operator page in a real browser (tests/system/gui.rs): headless Chromium driven by
// playwright-core. It prints one JSON object per line ({"event": ...}) for the Rust test,
// which checks the robot itself on the data plane.
//
// node gui.mjs URL ARTEFACT_DIR GOAL_X GOAL_Y [TIMEOUT_MS]
//   - loads the page, waits until the pose and the laser update;
//   - checks that no two labels of the contract graph overlap;
//   - clicks the goal on the map; waits until Planning's path to it is drawn, and until the
//     page's pose is within 0.5 m of it;
//   - waits until the robot moves again (the mission's next goal), presses STOP, waits until
//     the page shows it stopped;
//   - saves screenshots in ARTEFACT_DIR (gui-contracts, gui-path, gui-goal, gui-stop .png).
import { say, withPage } from "./launch.mjs";
import path from "node:path";

const [url, dir, gx, gy, timeoutArg] = process.argv.slice(2);
const goal = { x: Number(gx), y: Number(gy) };
const timeout = Number(timeoutArg || 120000);
await withPage(url, dir, async (page) => {
  const counts = () => page.evaluate(() => ({ ...window.hng.state.counts }));
  await page.waitForFunction(() => (window.hng.state.counts.pose || 0) >= 2 && (window.hng.state.counts.scan || 0) >= 2, null, { timeout });
  const c0 = await counts();
  await page.waitForFunction((c) => window.hng.state.counts.pose > c.pose + 3 && window.hng.state.counts.scan > c.scan + 3, c0, { timeout });
  const c1 = await counts();
  say({ event: "live", before: c0, after: c1 });

  // The contract graph: no two labels (the edges' and the modules' boxes) overlap.
  await page.waitForFunction(() => document.querySelectorAll("#contracts text.edge").length >= 4, null, { timeout });
  await page.waitForTimeout(600); // the next contracts frame, laid out again
  say({ event: "labels", ...(await page.evaluate(() => {
    const svg = document.getElementById("contracts");
    const b = (el) => { const r = el.getBBox(); return { x: r.x, y: r.y, w: r.width, h: r.height, t: el.textContent || "box" }; };
    const boxes = [...svg.querySelectorAll("text.edge")].map(b).concat([...svg.querySelectorAll("rect.node")].map(b));
    const hit = (p, q) => p.x < q.x + q.w && q.x < p.x + p.w && p.y < q.y + q.h && q.y < p.y + p.h;
    const overlaps = [];
    for (let i = 0; i < boxes.length; i++) for (let j = i + 1; j < boxes.length; j++) if (hit(boxes[i], boxes[j])) overlaps.push([boxes[i].t, boxes[j].t]);
    return { edges: svg.querySelectorAll("text.edge").length, nodes: svg.querySelectorAll("rect.node").length, overlaps };
  })) });
  await page.screenshot({ path: path.join(dir, "gui-contracts.png") });

  const [cx, cy] = await page.evaluate((g) => window.hng.view.worldToClient(g.x, g.y), goal);
  await page.mouse.click(cx, cy);
  await page.waitForFunction(() => window.hng.state.answers.length > 0, null, { timeout: 10000 });
  const answer = await page.evaluate(() => window.hng.state.answers[0]);
  say({ event: "goal_clicked", at: [cx, cy], answer, answer_text: await page.textContent("#answer") });
  // Planning's whole path to it (planning/path) drawn on the map, watched while the robot
  // goes (the arrival is caught the moment it happens).
  const pathDrawn = page.waitForFunction((g) => {
    const p = window.hng.state.path, pts = p && p.points;
    if (!pts || pts.length < 2 || window.hng.drawn.path !== pts.length) return false;
    const l = pts[pts.length - 1];
    return Math.hypot(l[0] - g.x, l[1] - g.y) < 0.3;
  }, goal, { timeout: 60000, polling: 50 }).then(async () => {
    say({ event: "path_drawn", drawn: await page.evaluate(() => window.hng.drawn.path), path: await page.evaluate(() => window.hng.state.path) });
    // The page on its way: map, laser, path, camera and panels (docs/img/operator-page.png).
    await page.screenshot({ path: path.join(dir, "gui-path.png") });
  });
  await page.waitForFunction((g) => {
    const p = window.hng.state.pose && window.hng.state.pose.pose;
    return p && Math.hypot(p.x - g.x, p.y - g.y) < 0.5;
  }, goal, { timeout, polling: 50 });
  say({ event: "goal_reached_on_page", pose: await page.evaluate(() => window.hng.state.pose.pose) });
  await pathDrawn;
  await page.screenshot({ path: path.join(dir, "gui-goal.png") });

  // The mission resumes once the operator's goal is done: wait for motion, then STOP.
  await page.waitForFunction(() => window.hng.state.odom && Math.abs(window.hng.state.odom.vx) > 0.15, null, { timeout, polling: 20 });
  say({ event: "moving", vx: await page.evaluate(() => window.hng.state.odom.vx) });
  await page.click("#stop");
  say({ event: "stop_clicked" });
  await page.waitForFunction(() => window.hng.state.odom && Math.abs(window.hng.state.odom.vx) < 0.01, null, { timeout: 20000, polling: 20 });
  say({ event: "stopped_on_page", answer_text: await page.textContent("#answer"), level: await page.textContent("#level") });
  await page.waitForTimeout(300); // let the panels draw for the screenshot
  await page.screenshot({ path: path.join(dir, "gui-stop.png") });
});
