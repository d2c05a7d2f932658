// Browser test of the ima web console: `ima demo --web 127.0.0.1:0 --speed 4` driven from
// Debian's Chromium through playwright-core. Run by `.ci/run` (or `npm test` here, after
// `cargo build`). Screenshots go to $IMA_BROWSER_OUT (default tests/browser/output/).
import { spawn } from 'node:child_process';
import { mkdirSync } from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = path.dirname(fileURLToPath(import.meta.url));
const root = path.resolve(here, '..', '..');
const bin = process.env.IMA_BIN || path.join(root, 'target', 'debug', 'ima');
const out = process.env.IMA_BROWSER_OUT || path.join(here, 'output');
const browserPath = process.env.CHROMIUM || '/usr/bin/chromium';
mkdirSync(out, { recursive: true });

function fail(msg) {
  console.error(`browser test FAILED: ${msg}`);
  process.exitCode = 1;
  throw new Error(msg);
}
function check(cond, msg) { if (!cond) fail(msg); else console.log(`  ok: ${msg}`); }

// Start the demo and read the console's address from its stderr.
const demo = spawn(bin, ['demo', '--web', '127.0.0.1:0', '--speed', '4', '--svg', path.join(out, 'demo.svg')],
  { stdio: ['ignore', 'pipe', 'pipe'] });
let stderr = '';
demo.stdout.on('data', (d) => { stderr += d; });
const url = await new Promise((resolve, reject) => {
  const t = setTimeout(() => reject(new Error(`no console address within 30 s; stderr:\n${stderr}`)), 30000);
  demo.stderr.on('data', (d) => {
    stderr += d;
    const m = /web console at (http:\/\/\S+)/.exec(stderr);
    if (m) { clearTimeout(t); resolve(m[1]); }
  });
  demo.on('exit', (code) => reject(new Error(`ima demo exited (${code}) before serving:\n${stderr}`)));
});
console.log(`console at ${url}`);

const browser = await chromium.launch({
  executablePath: browserPath,
  headless: true,
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
    '--disable-background-networking', '--disable-component-update', '--disable-sync'],
});
try {
  const page = await browser.newPage({ viewport: { width: 1100, height: 900 } });
  page.on('pageerror', (e) => fail(`page error: ${e.message}`));
  await page.goto(url);
  await page.waitForSelector('tr.target', { timeout: 30000 });
  check(await page.locator('tr.target').count() === 3, 'the three targets are listed');

  // Bad input gets a clear message.
  await page.fill('#add-colour', 'pink');
  await page.click('#add');
  await page.waitForFunction(() => document.getElementById('message').textContent.includes('unknown colour "pink"'));
  check(true, 'an unknown colour is refused with a message');

  // Add two targets, move one up, cancel both.
  for (const c of ['yellow', 'orange']) {
    await page.fill('#add-colour', c);
    await page.click('#add');
    await page.waitForSelector(`tr.target[data-target="${c}"]`);
  }
  await page.click('tr.target[data-target="orange"] button.up');
  await page.waitForSelector('tr.target[data-target="orange"][data-index="3"]');
  check(true, 'a waiting target moves up');
  for (const c of ['yellow', 'orange']) {
    await page.click(`tr.target[data-target="${c}"] button.cancel`);
    await page.waitForSelector(`tr.target[data-target="${c}"][data-state="failed"]`);
    const text = await page.textContent(`tr.target[data-target="${c}"] td.state`);
    check(text.includes('cancelled'), `the cancel button cancelled ${c} ("${text.trim()}")`);
  }

  // Map: two robots.
  await page.click('nav [data-tab="map"]');
  await page.waitForFunction(() => document.querySelectorAll('#map-robots li').length === 2, null, { timeout: 30000 });
  const names = await page.$$eval('#map-robots li', (l) => l.map((x) => x.dataset.robot).sort());
  check(JSON.stringify(names) === '["scooter","skeeter"]', `the map shows two robots (${names})`);
  // Skeeter's SES: bearings with ranges where its vision has one (drawn as segments + dots).
  await page.waitForSelector('#map-ses li.ses-mark[data-ranged="yes"]', { timeout: 60000 });
  const marks = await page.$$eval('#map-ses li.ses-mark', (l) => l.map((x) => x.textContent));
  check(marks.some((t) => /range \d+\.\d+ m/.test(t)), `the map draws SES bearings with ranges (${marks.length} marks, e.g. "${marks[0]}")`);

  // SAN: activations change over time.
  await page.click('nav [data-tab="san"]');
  await page.waitForSelector('.card.san td.act', { timeout: 30000 });
  const acts = () => page.$$eval('.card.san td.act', (l) => l.map((x) => x.textContent).join(' '));
  const first = await acts();
  let changed = false;
  for (let i = 0; i < 30 && !changed; i++) {
    await page.waitForTimeout(500);
    changed = (await acts()) !== first;
  }
  check(changed, 'the SAN page shows changing activations');
  await page.screenshot({ path: path.join(out, 'console-san.png'), fullPage: true });

  // Peer Agents: a card per process with counters.
  await page.click('nav [data-tab="peer"]');
  await page.waitForFunction(() => document.querySelectorAll('.card.peer').length >= 2);
  check((await page.textContent('#peer')).includes('broadcasts'), 'the Peer Agent page shows broadcast counters');
  // Link health: Skeeter's manager counts Scooter's heartbeats; the count grows on screen.
  const hb = '.card.peer[data-robot="skeeter"] li.link .hb-rx';
  await page.waitForSelector(hb, { timeout: 30000 });
  const hb0 = Number(await page.textContent(hb));
  await page.waitForFunction(([sel, n]) => {
    const e = document.querySelector(sel);
    return e && Number(e.textContent) > n;
  }, [hb, hb0], { timeout: 30000 });
  check(true, `a heartbeat counter increases on the Peer page (from ${hb0} to ${await page.textContent(hb)})`);
  const peerText = await page.textContent('#peer');
  check(/request priority \d+/.test(peerText) && peerText.includes('auth failures'),
    'the Peer page shows request priorities and refused-frame counters');
  await page.screenshot({ path: path.join(out, 'console-peer.png'), fullPage: true });

  // Mission: the three targets reach "done" on screen.
  await page.click('nav [data-tab="mission"]');
  for (const c of ['red', 'blue', 'green']) {
    await page.waitForSelector(`tr.target[data-target="${c}"][data-state="done"]`, { timeout: 150000 });
    const text = await page.textContent(`tr.target[data-target="${c}"] td.state`);
    check(text.trim() === 'done', `target ${c} is done on screen`);
  }
  await page.waitForSelector('#summary:not([hidden])', { timeout: 30000 });
  check((await page.textContent('#summary')).includes('3 done'), 'the summary stays on the page after the mission');
  await page.screenshot({ path: path.join(out, 'console-mission.png'), fullPage: true });

  // Esc asks for a fleet stop (after the mission, the console says it takes no more commands).
  await page.keyboard.press('Escape');
  await page.waitForFunction(() => document.getElementById('message').textContent.includes('mission is over'));
  check(true, 'Esc sends the fleet stop (refused with a message once the mission is over)');

  await page.click('nav [data-tab="map"]');
  await page.waitForTimeout(500);
  await page.screenshot({ path: path.join(out, 'console-map.png'), fullPage: true });

  // A narrow window: nothing wider than the screen.
  await page.setViewportSize({ width: 380, height: 800 });
  await page.click('nav [data-tab="mission"]');
  const overflow = await page.evaluate(() => document.documentElement.scrollWidth - window.innerWidth);
  check(overflow <= 1, `works in a narrow window (overflow ${overflow}px)`);
  await page.screenshot({ path: path.join(out, 'console-narrow.png'), fullPage: true });
  console.log(`browser test passed; screenshots in ${out}`);
} finally {
  await browser.close();
  demo.kill('SIGINT');
  await new Promise((r) => { if (demo.exitCode !== null) r(); else demo.on('exit', r); });
}
