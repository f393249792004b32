// The live viewer in a real browser: Debian's chromium, headless, driven by
// playwright-core, against `pp5echo run --view` streaming a paced simulated
// sweep through the MPI pipeline (or, with --serial, the one-process
// pipeline). Checks what issue 16 asks of the page and measures what a person
// would feel (docs/benchmarks.md).
//
// Usage: node viewer_test.mjs --pp5echo BIN --out DIR [--ranks 4 | --serial] [--pace 15]
//          [--set key=value ...] [--measure]
// Exit status 0 when every check holds; DIR gets screenshot.png,
// figures.json and the run's own outputs.
import {chromium} from 'playwright-core';
import {spawn} from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import {fileURLToPath} from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, '..', '..');
const args = process.argv.slice(2);
const opt = (name, def) => {
  const i = args.indexOf(name);
  return i >= 0 ? args[i + 1] : def;
};
const sets = args.flatMap((a, i) => (a === '--set' ? ['--set', args[i + 1]] : []));
const bin = opt('--pp5echo');
const out = path.resolve(opt('--out', 'viewer-test'));
const ranks = opt('--ranks', '4');
const pace = opt('--pace', '15');
const measure = args.includes('--measure');
const serial = args.includes('--serial');
fs.mkdirSync(out, {recursive: true});

const failures = [];
function check(ok, what) {
  console.log(`${ok ? 'ok  ' : 'FAIL'} ${what}`);
  if (!ok) failures.push(what);
}
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
async function until(page, fn, arg, ms, what) {
  try {
    await page.waitForFunction(fn, arg, {timeout: ms, polling: 50});
    return true;
  } catch (e) {
    console.log(`  (timed out after ${ms} ms waiting for ${what})`);
    return false;
  }
}

// The browser first, as a person's would be open before the scan starts.
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-component-update',
         '--disable-sync', '--no-first-run', '--disable-quic'],
});
const context = await browser.newContext({viewport: {width: 1400, height: 1000}});
let page = await context.newPage();
page.on('pageerror', (e) => failures.push('page error: ' + e.message));

// ---- the run ------------------------------------------------------------------
const runArgs = [ranks, bin, 'run', path.join(repo, 'configs/doll.toml'), '-o', path.join(out, 'run'), '--view', '127.0.0.1:0',
                 '--serve', '--set', `run.pace_fps=${pace}`, '--set', 'run.orbit_frames=0',
                 '--set', 'sim.sweep.capture_interval_mm=1', ...sets];
// One process: the same run without mpirun (runArgs less the rank count).
const launch = serial ? [bin, [...runArgs.slice(2), '--serial']] : ['bash', [path.join(repo, 'scripts/mpirun.sh'), ...runArgs]];
console.log('run: ' + (serial ? launch[0] + ' ' : 'scripts/mpirun.sh ') + launch[1].join(' '));
const run = spawn(launch[0], launch[1], {stdio: ['ignore', 'pipe', 'pipe']});
let runLog = '', timedLog = '';
const urlPromise = new Promise((resolve, reject) => {
  const onData = (d) => {
    runLog += d.toString();
    timedLog += `[${Date.now()}] ${d.toString()}`;  // when each piece came (run.log, for a person)
    const m = runLog.match(/viewer: open (http:\/\/\S+)/);
    if (m) resolve(m[1]);
  };
  run.stdout.on('data', onData);
  run.stderr.on('data', onData);
  run.on('exit', (code) => reject(new Error(`the run ended (${code}) before printing its URL:\n${runLog}`)));
  setTimeout(() => reject(new Error('no viewer URL within 60 s:\n' + runLog)), 60000);
});
const runExit = new Promise((resolve) => run.on('exit', (code) => resolve(code)));
const url = await urlPromise;
console.log('viewer: ' + url);

const figures = {};
let recordingFile = '';  // the page's recording, as the host named it
const events = [];  // what the test did when (with --measure, beside the latencies)
const mark = (what) => events.push({what, at: Date.now()});
try {
  await page.goto(url);

  // 1. The image builds up while frames arrive.
  check(await until(page, () => window.pp5.images > 0, null, 30000, 'a first image'), 'the page shows an image');
  // Recording from the page, while the sweep goes on (checked in the file after the run).
  mark('record');
  await page.locator('#record').click();
  check(await until(page, () => window.pp5.stats && window.pp5.stats.recording !== '', null, 10000, 'recording'),
        'the record button starts a recording');
  // The file this recording writes (earlier runs in the same folder left others).
  recordingFile = await page.evaluate(() => window.pp5.stats.recording);
  const cov0 = await page.evaluate(() => window.pp5.coverage);
  const t0 = Date.now(), n0 = await page.evaluate(() => window.pp5.images);
  check(await until(page, () => window.pp5.distinct.size >= 20, null, 60000, '20 distinct images'),
        'the 3D image changes as frames arrive (at least 20 distinct images)');
  const sweep = await page.evaluate(() => ({images: window.pp5.images, distinct: window.pp5.distinct.size,
                                            stats: window.pp5.stats, outlines: window.pp5.outlines}));
  figures.sweep_images_per_s = (sweep.images - n0) / ((Date.now() - t0) / 1000);
  mark('screenshot');
  await page.screenshot({path: path.join(out, 'screenshot.png')});  // the doll building up (docs/viewer.md)
  mark('screenshot done');
  check(sweep.outlines > 0, 'the newest frame\'s outline is drawn over the 3D view');
  mark('record stop');
  await page.locator('#record').click();
  check(await until(page, () => window.pp5.stats.recording === '', null, 10000, 'recording to stop'),
        'the record button stops it');
  // 2. A drag during the sweep rotates the view; the pipeline records the new
  // epoch. What a person feels: how soon the view first follows the mouse
  // (from the drag's first view message) and how many views a second it then
  // shows (images answering the drag's view messages, not the frames' images
  // in between).
  const snap = () => page.evaluate(() => ({images: window.pp5.images, epoch: window.pp5.epoch,
                                           last: window.pp5.lastImage, distinct: window.pp5.distinct.size}));
  await page.locator('#render').scrollIntoViewIfNeeded();  // clicks elsewhere may have scrolled the page
  const box = await page.locator('#render').boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  if (process.env.PP5_DEBUG) await page.screenshot({path: path.join(out, 'before-drag.png')});
  const before = await snap();
  const seq0 = await page.evaluate(() => window.pp5.viewSent());
  figures.drag_during_sweep = !(await page.evaluate(() => window.pp5.stats.ended));  // frames still coming in
  mark('drag');
  const dragStart = Date.now();
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  // A mouse reports its moves at 60 Hz or more: a move every 16 ms (the page
  // sends one view message per animation frame), 120 pixels in all.
  for (let i = 1; i <= 60; ++i) {
    await page.mouse.move(cx + 2 * i, cy + (2 * i) / 3);
    await sleep(16);
  }
  const dragEnd = Date.now();
  const dragSeconds = (dragEnd - dragStart) / 1000;
  // The coarse image a drag shows, before the mouse is let go (docs/viewer.md).
  await page.locator('#render').screenshot({path: path.join(out, 'during-a-drag.png')});
  await page.mouse.up();
  // The drag's own images: those answering its view messages (the run may open
  // epochs of its own meanwhile, e.g. at the end of the sweep).
  const dragged = await until(page, (s) => window.pp5.viewResponses.some((r) => r.seq > s), seq0, 60000,
                              'the dragged view');
  const responses = (await page.evaluate(() => window.pp5.viewResponses)).filter((r) => r.seq > seq0);
  const firstSentAt = await page.evaluate((s) => window.pp5.viewSentAt(s), seq0 + 1);
  check(dragged && responses.length > 0, `a drag changes the view (epoch ${before.epoch} -> ${(await snap()).epoch})`);
  if (!dragged) {  // what the page knew, to tell a lost message from a lost image
    console.log('  diagnostics: ' + JSON.stringify(await page.evaluate(() => ({
      sent: window.pp5.viewSent(), last: window.pp5.lastImage && {...window.pp5.lastImage, arrivals: undefined},
      state: window.pp5.state && {azimuth: window.pp5.state.azimuth, elevation: window.pp5.state.elevation},
      stats: window.pp5.stats, errors: window.pp5.errors}))));
  }
  figures.drag_images_per_s = responses.filter((r) => r.at <= dragEnd).length / dragSeconds;
  figures.drag_first_response_ms = responses.length && firstSentAt ? responses[0].at - firstSentAt : null;
  figures.drag_responses = responses.length;
  if (measure) figures.drag_first_response = responses[0];
  const dragEpoch = (await snap()).epoch;

  // Pause: no frame goes into the pipeline until resume. (The test's own
  // sweep is long enough for this to come before its end; the measurement's,
  // the default doll's 3 s, usually is not.)
  const endedBeforePause = await page.evaluate(() => window.pp5.stats.ended);
  if (!measure) check(!endedBeforePause, 'the sweep is still going when the test pauses it');
  mark('pause');
  await page.locator('#pause').click();
  check(await until(page, () => window.pp5.stats.paused, null, 10000, 'the pause'), 'pause is acknowledged');
  await sleep(600);
  const f1 = await page.evaluate(() => window.pp5.stats.frames);
  await sleep(1200);
  const f2 = await page.evaluate(() => window.pp5.stats.frames);
  check(f2 === f1, `no frame goes in while paused (${f1} then ${f2})`);
  mark('resume');
  await page.locator('#pause').click();
  if (!(await page.evaluate(() => window.pp5.stats.ended)))
    check(await until(page, (f) => window.pp5.stats.frames > f || window.pp5.stats.ended, f2, 10000, 'frames again'),
          'frames go in again after resume');
  check(await until(page, (c) => window.pp5.coverage > c, cov0, 20000, 'coverage to rise'),
        `the coverage fraction rises during the sweep (from ${cov0})`);
  check(await until(page, () => window.pp5.bmodes > 0, null, 10000, 'a B-mode frame'), 'the B-mode frame is shown');
  // The rest steers the final volume the run serves (--serve): no new frame
  // changes the image meanwhile, so each change below is the control's own.
  // (`ended` comes first, when the input ends; `serving` once the run's own
  // final images, which show other modes, are done.)
  check(await until(page, () => window.pp5.stats.ended && window.pp5.stats.serving, null, 60000, 'the final volume'),
        'the sweep ends and the final volume is served');

  // 3. The transfer function, the MIP switch and a slice slider each change what is shown.
  // An image of a newer epoch whose header says `key` is `value`, and whose
  // pixels differ from the image shown when the control was changed. (Not
  // "never seen before": the run's own final images, before it serves the
  // volume, include MIP in the same view, which ignores the transfer function.)
  const changes = async (what, key, value, act) => {
    const b = await snap();
    const shown = await page.evaluate(() => window.pp5.recentImages.at(-1).hash);
    await act();
    const ok = await until(page, ([e, k, v, h]) => window.pp5.recentImages.some(
                             (i) => i.epoch > e && i[k] === v && i.hash !== h),
                           [b.epoch, key, value, shown], 60000, what);
    await sleep(300);
    const a = await snap();
    await page.screenshot({path: path.join(out, `after-${what.replace(/\W+/g, '-')}.png`)});
    if (!ok)  // what came after the change
      console.log(`  images after ${what} (${shown} shown before): ` +
                  JSON.stringify((await page.evaluate(() => window.pp5.recentImages)).filter((i) => i.epoch > b.epoch)));
    check(ok, `${what} changes the image (epoch ${b.epoch} -> ${a.epoch})`);
  };
  await changes('the transfer function', 'preset', 'strong echoes',
                () => page.locator('#tf-preset').selectOption('strong echoes'));
  await changes('the MIP switch', 'composite', 'mip', () => page.locator('input[name=composite][value=mip]').check());
  const mpr0 = () => page.evaluate(() => document.getElementById('mpr0').toDataURL());
  check(await until(page, () => window.pp5.mprs[0] > 0, null, 20000, 'a slice'), 'the slices are shown');
  const sliceBefore = await mpr0();
  const mprCount = await page.evaluate(() => window.pp5.mprs[0]);
  await page.locator('#mpr-pos0').fill('200');
  await page.locator('#mpr-pos0').dispatchEvent('input');
  await until(page, (n) => window.pp5.mprs[0] > n, mprCount, 20000, 'a moved slice');
  check((await mpr0()) !== sliceBefore, 'the MPR slider changes the slice');
  await page.locator('input[name=composite][value=over]').check();
  await until(page, () => window.pp5.lastImage.composite === 'over', null, 60000, 'the over image again');

  // 4. A bad control message gets an error reply and the run goes on.
  figures.latency_ms = await page.evaluate(() => window.pp5.latencies);
  if (measure) {
    figures.latency_parts = await page.evaluate(() => window.pp5.latencyParts);
    figures.events = events;
  }
  const errs = await page.evaluate(() => window.pp5.errors.length);
  await page.evaluate(() => window.pp5.send({type: 'tf', level: 999, window: 1, opacity: 1}));
  await page.evaluate(() => window.pp5.send({type: 'no such thing'}));
  check(await until(page, (n) => window.pp5.errors.length >= n + 2, errs, 10000, 'error replies'),
        'bad control messages get error replies: ' + JSON.stringify(await page.evaluate(() => window.pp5.errors)));
  const afterBad = await snap();
  await page.locator('input[name=composite][value=additive]').check();
  check(await until(page, (e) => window.pp5.epoch > e && window.pp5.lastImage.composite === 'additive', afterBad.epoch,
                    60000, 'an image after the bad messages'), 'the run goes on after them');
  await page.locator('input[name=composite][value=over]').check();
  await until(page, () => window.pp5.lastImage.composite === 'over', null, 60000, 'the over image again');

  // 5. Closing and reopening the page resumes the stream.
  await page.close();
  await sleep(500);
  page = await context.newPage();
  page.on('pageerror', (e) => failures.push('page error: ' + e.message));
  await page.goto(url);
  check(await until(page, () => window.pp5.images > 0 && window.pp5.state !== null, null, 20000, 'images again'),
        'a reopened page gets the stream again');

  figures.drag_epoch = dragEpoch;
} finally {
  await browser.close();
}

// The run ends cleanly on Ctrl-C (what mpirun.sh turns SIGINT into).
run.kill('SIGINT');
const code = await Promise.race([runExit, sleep(120000).then(() => 'timeout')]);
check(code === 0, `the run ends cleanly after Ctrl-C (exit ${code})`);
if (code !== 0) console.log(runLog.slice(-3000));

// The pipeline recorded the dragged view's epoch.
try {
  const csv = fs.readFileSync(path.join(out, 'run', 'stats.csv'), 'utf8').trim().split('\n');
  const col = csv[0].split(',').indexOf('epoch');
  const epochs = new Set(csv.slice(1).map((l) => +l.split(',')[col]));
  check(epochs.has(figures.drag_epoch), `stats.csv has rows of the dragged view's epoch ${figures.drag_epoch}`);
} catch (e) {
  check(false, 'stats.csv: ' + e.message);
}

// The page's recording: a PLUS sequence of the frames sent while it was on.
try {
  const info = JSON.parse(await new Promise((resolve, reject) => {
    const p = spawn(bin, ['info', recordingFile]);
    let o = '';
    p.stdout.on('data', (d) => (o += d));
    p.on('exit', (c) => (c === 0 ? resolve(o) : reject(new Error('pp5echo info exit ' + c))));
  }));
  check(info.frame_count > 0 && info.transforms.ImageToReference && info.transforms.ImageToReference.valid_frames === info.frame_count,
        `the recording holds ${info.frame_count} frames, each with its ImageToReference`);
} catch (e) {
  check(false, 'the recording: ' + e.message);
}

// `pp5echo view` shows the volume the run wrote, in the same page.
{
  const view = spawn(bin, ['view', path.join(out, 'run', 'volume.mha'), '--view', '127.0.0.1:0'],
                     {stdio: ['ignore', 'pipe', 'pipe']});
  let log = '';
  const viewUrl = await new Promise((resolve) => {
    const onData = (d) => {
      log += d.toString();
      const m = log.match(/viewer: open (http:\/\/\S+)/);
      if (m) resolve(m[1]);
    };
    view.stdout.on('data', onData);
    view.stderr.on('data', onData);
    view.on('exit', () => resolve(null));
    setTimeout(() => resolve(null), 30000);
  });
  check(viewUrl !== null, 'pp5echo view prints its URL' + (viewUrl ? '' : ':\n' + log));
  if (viewUrl) {
    const b = await chromium.launch({executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
                                     args: ['--headless', '--no-sandbox', '--disable-gpu', '--no-first-run']});
    try {
      const p = await b.newPage();
      await p.goto(viewUrl);
      check(await until(p, () => window.pp5.images > 0 && window.pp5.mprs[1] > 0, null, 30000, 'the volume'),
            'pp5echo view shows the volume and its slices');
      const over = await p.evaluate(() => window.pp5.recentImages.at(-1).hash);
      await p.locator('input[name=composite][value=mip]').check();
      check(await until(p, (h) => window.pp5.lastImage && window.pp5.lastImage.composite === 'mip' &&
                                  window.pp5.recentImages.at(-1).hash !== h, over, 30000, 'MIP'),
            'pp5echo view steers like a run (MIP)');
      check(await p.evaluate(() => window.pp5.stats && window.pp5.stats.serving),
            'pp5echo view says the page steers the volume');
    } finally {
      await b.close();
    }
  }
  const viewExit = new Promise((resolve) => view.on('exit', (c) => resolve(c)));
  view.kill('SIGINT');
  const c = await Promise.race([viewExit, sleep(30000).then(() => 'timeout')]);
  check(c === 0, `pp5echo view ends cleanly on Ctrl-C (exit ${c})`);
}

const lat = (figures.latency_ms || []).slice().sort((a, b) => a - b);
const q = (p) => (lat.length ? lat[Math.min(lat.length - 1, Math.ceil(p * lat.length) - 1)] : null);
figures.latency_ms_median = q(0.5);
figures.latency_ms_p95 = q(0.95);
figures.latency_frames = lat.length;
if (!measure) delete figures.latency_ms;
fs.writeFileSync(path.join(out, 'run.log'), timedLog);
fs.writeFileSync(path.join(out, 'figures.json'), JSON.stringify(figures, null, 2) + '\n');
console.log('figures: ' + JSON.stringify(figures));
if (measure) console.log('(measured: the checks above are what the test asserts; the figures go to docs/benchmarks.md)');
if (failures.length) {
  console.log(`${failures.length} check(s) failed:\n  ` + failures.join('\n  '));
  process.exit(1);
}
console.log('all checks hold');
process.exit(0);  // not waiting for the timers of the checks that did not need them
