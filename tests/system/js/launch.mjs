// Headless Debian Chromium for the browser tests, with a fresh profile in DIR (playwright
// takes --user-data-dir as launchPersistentContext's first argument). Chromium sometimes dies
// while starting (seen once in a CI rehearsal: SIGTRAP before the first page): a launch that
// fails is said on stderr and tried again, at most three times; the page's own checks are never
// retried.
import { chromium } from "playwright-core";
import path from "node:path";
import fs from "node:fs";

// Returns { browser, userDir }: the caller removes userDir after closing the browser. `say`
// (optional) also reports each failed start as a {"event": "launch_failed"} line. A start may
// take 60 s (a loaded CI machine) before it counts as failed.
export async function launchBrowser(dir, say) {
  fs.mkdirSync(dir, { recursive: true });
  for (let attempt = 1; ; attempt++) {
    const userDir = fs.mkdtempSync(path.join(dir, "profile-"));
    try {
      const browser = await chromium.launchPersistentContext(userDir, {
        executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
        headless: true,
        timeout: 60000,
        viewport: { width: 1500, height: 950 },
        args: [
          "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync",
        ],
      });
      return { browser, userDir };
    } catch (e) {
      fs.rmSync(userDir, { recursive: true, force: true });
      const first = String(e).split("\n")[0];
      if (say) say({ event: "launch_failed", attempt, error: first });
      if (attempt >= 3) throw e;
      process.stderr.write(`chromium failed to start (attempt ${attempt} of 3): ${first}\n`);
    }
  }
}

// One JSON object per line on stdout ({"event": ...}), for the Rust test.
export const say = (o) => process.stdout.write(JSON.stringify(o) + "\n");

// Opens `url` in a browser of its own (profile and artefacts in `dir`), runs `script(page)`,
// says {"event": "done"} and exits the process. Everything, the browser's start included, is
// inside the try: a failure is one {"event": "error"} line on stdout and exit status 1, never a
// silent exit (the test shows it with the exit status and stderr). The page's own errors are
// {"event": "page_error"} lines.
export async function withPage(url, dir, script) {
  let code = 0, browser = null, userDir = null;
  try {
    ({ browser, userDir } = await launchBrowser(dir, say));
    const page = browser.pages()[0] || (await browser.newPage());
    page.on("pageerror", (e) => say({ event: "page_error", error: String(e) }));
    await page.goto(url);
    await script(page);
    say({ event: "done" });
  } catch (e) {
    say({ event: "error", error: String(e && e.stack || e) });
    code = 1;
  } finally {
    if (browser) await browser.close().catch(() => {});
    if (userDir) fs.rmSync(userDir, { recursive: true, force: true });
  }
  process.exit(code);
}
