#!/usr/bin/env node
// Opens a page of `tofu report` in Debian's headless chromium (playwright-core drives the
// system browser; no browser is downloaded) and checks what a reader would see:
//   - no console error, no uncaught page error, no failed request, and no request that
//     leaves the page's own folder (the page must work without network);
//   - every image decoded, every relative link and media source names an existing file;
//   - the document has content (height, text) and a full-page screenshot that is not blank
//     (decoded in the page through a canvas: distinct colours, share of non-white pixels);
//   - with --plot: every interactive plot is drawn; hovering the first one shows a tooltip
//     with the time and a value in metres; wheel and drag zoom in time, double-click resets.
// Exits 1 naming every failure, 2 on bad usage.
//
//   node check_report.mjs PAGE.html --screenshot OUT.png [--plot] [--expect TEXT]... [--also PAGE]...

import fs from 'node:fs';
import path from 'node:path';
import process from 'node:process';
import { pathToFileURL } from 'node:url';

import { chromium } from 'playwright-core';

const kChromium = process.env.TOFU_CHROMIUM || '/usr/bin/chromium';

function usage(message) {
  console.error(`check_report: ${message}`);
  console.error('usage: node check_report.mjs PAGE.html --screenshot OUT.png [--plot] [--expect TEXT]... [--also PAGE]...');
  process.exit(2);
}

function parseArgs(argv) {
  const options = { page: null, screenshot: null, plot: false, expect: [], also: [] };
  for (let i = 0; i < argv.length; i++) {
    const arg = argv[i];
    if (arg === '--plot') options.plot = true;
    else if (arg === '--screenshot') options.screenshot = argv[++i];
    else if (arg === '--expect') options.expect.push(argv[++i]);
    else if (arg === '--also') options.also.push(argv[++i]);
    else if (arg.startsWith('--')) usage(`unknown option ${arg}`);
    else if (options.page === null) options.page = arg;
    else usage(`unexpected argument ${arg}`);
  }
  if (!options.page) usage('no page given');
  if (!options.screenshot) usage('--screenshot OUT.png is required');
  if (options.expect.some((t) => t === undefined)) usage('--expect needs a text');
  for (const page of [options.page, ...options.also]) {
    if (!page || !fs.existsSync(page)) usage(`no such page: ${page}`);
  }
  return options;
}

// Distinct colours (4 bits per channel) and the share of pixels that are not near-white,
// of a PNG decoded by the browser itself (no PNG decoder needed here).
async function screenshotStatistics(browser, png) {
  const page = await browser.newPage();
  try {
    await page.setContent('<canvas id="c"></canvas>');
    return await page.evaluate(async (dataUrl) => {
      const image = new Image();
      image.src = dataUrl;
      await image.decode();
      const scale = Math.min(1, 1000 / image.width);
      const canvas = document.getElementById('c');
      canvas.width = Math.max(1, Math.round(image.width * scale));
      canvas.height = Math.max(1, Math.round(image.height * scale));
      const ctx = canvas.getContext('2d');
      ctx.drawImage(image, 0, 0, canvas.width, canvas.height);
      const data = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
      const colours = new Set();
      let inked = 0;
      for (let i = 0; i < data.length; i += 4) {
        colours.add(((data[i] >> 4) << 8) | ((data[i + 1] >> 4) << 4) | (data[i + 2] >> 4));
        if (data[i] < 235 || data[i + 1] < 235 || data[i + 2] < 235) inked++;
      }
      return { width: image.width, height: image.height, colours: colours.size, inked: inked / (data.length / 4) };
    }, `data:image/png;base64,${png.toString('base64')}`);
  } finally {
    await page.close();
  }
}

async function checkPlots(page, problems) {
  const plots = page.locator('.tofu-plot');
  const count = await plots.count();
  if (count === 0) {
    problems.push('no interactive plot (.tofu-plot) on the page');
    return;
  }
  const ready = await page.locator('.tofu-plot[data-ready="1"]').count();
  if (ready !== count) problems.push(`${count - ready} of ${count} plots were not drawn (script failed?)`);
  // Each canvas has ink: axes, ticks and at least one line.
  const inks = await page.evaluate(() => Array.from(document.querySelectorAll('.tofu-plot canvas')).map((c) => {
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) if (d[i] < 200 || d[i + 1] < 200 || d[i + 2] < 200) n++;
    return n;
  }));
  inks.forEach((n, i) => { if (n < 500) problems.push(`plot ${i + 1}: canvas nearly empty (${n} dark pixels)`); });

  const first = plots.first();
  const canvas = first.locator('canvas');
  await canvas.scrollIntoViewIfNeeded();
  const box = await canvas.boundingBox();
  if (!box || box.width < 200 || box.height < 100) {
    problems.push(`plot canvas too small: ${JSON.stringify(box)}`);
    return;
  }
  const tip = first.locator('.plot-tip');
  await page.mouse.move(box.x + box.width * 0.55, box.y + box.height * 0.45);
  try {
    await tip.waitFor({ state: 'visible', timeout: 5000 });
  } catch {
    problems.push('hovering the plot shows no tooltip');
    return;
  }
  const text = (await tip.innerText()).replace(/\s+/g, ' ');
  if (!/t = -?[0-9.]+(e[-+]?[0-9]+)? s/.test(text)) problems.push(`tooltip has no time: "${text}"`);
  if (!/: -?[0-9.]+(e[-+]?[0-9]+)? m\b/.test(text)) problems.push(`tooltip has no value in metres: "${text}"`);

  // Zoom: the wheel narrows the time range, double-click restores it, a drag selects one.
  const range = first.locator('.plot-range');
  await page.mouse.wheel(0, -300);
  await page.waitForTimeout(100);
  if (!/^Showing /.test(await range.innerText())) problems.push('the wheel did not zoom the plot');
  await page.mouse.dblclick(box.x + box.width * 0.55, box.y + box.height * 0.45);
  await page.waitForTimeout(100);
  if ((await range.innerText()).trim() !== '') problems.push('double-click did not reset the zoom');
  await page.mouse.move(box.x + box.width * 0.3, box.y + box.height * 0.5);
  await page.mouse.down();
  await page.mouse.move(box.x + box.width * 0.6, box.y + box.height * 0.5, { steps: 5 });
  await page.mouse.up();
  await page.waitForTimeout(100);
  if (!/^Showing /.test(await range.innerText())) problems.push('dragging across the plot did not zoom it');
  await page.mouse.dblclick(box.x + box.width * 0.55, box.y + box.height * 0.45);
  await page.mouse.move(0, 0);
}

// Every check above on one page, in its own browser context; its problems are appended
// to `problems` with the page's name.
async function checkPage(browser, pagePath, screenshotPath, options, withPlot, problems) {
  const pageDir = path.dirname(pagePath);
  const context = await browser.newContext({ viewport: { width: 1280, height: 900 } });
  const found = [];
  try {
    const page = await context.newPage();
    page.setDefaultTimeout(15000);
    page.on('console', (m) => { if (m.type() === 'error') found.push(`console error: ${m.text()}`); });
    page.on('pageerror', (e) => found.push(`page error: ${e.message}`));
    page.on('requestfailed', (r) => {
      // A <video preload="metadata"> aborts its own load once it has the metadata: not a
      // failure (a missing clip is caught below as a link to a missing file).
      if (r.resourceType() === 'media' && r.failure()?.errorText === 'net::ERR_ABORTED') return;
      found.push(`failed request: ${r.url().slice(0, 120)} (${r.failure()?.errorText})`);
    });
    page.on('request', (r) => {
      const url = r.url();
      if (url.startsWith('data:') || url.startsWith('blob:')) return;
      if (!url.startsWith('file:')) found.push(`request to the network: ${url}`);
      else if (!decodeURIComponent(new URL(url).pathname).startsWith(pageDir + path.sep) &&
               decodeURIComponent(new URL(url).pathname) !== pagePath) {
        found.push(`request outside the report's folder: ${url}`);
      }
    });
    await page.goto(pathToFileURL(pagePath).href, { waitUntil: 'load' });

    const facts = await page.evaluate(() => ({
      height: document.body.scrollHeight,
      text: document.body.innerText,
      title: document.title,
      images: Array.from(document.images).map((i) => ({ src: i.getAttribute('src').slice(0, 60), ok: i.complete && i.naturalWidth > 0 })),
      refs: Array.from(document.querySelectorAll('a[href], img[src], video[src], source[src]'))
        .map((e) => e.getAttribute('href') ?? e.getAttribute('src')),
    }));
    if (!facts.title) found.push('the page has no title');
    if (facts.height < 400) found.push(`the page is only ${facts.height} px high`);
    if (facts.text.trim().length < 200) found.push(`the page has almost no text (${facts.text.trim().length} characters)`);
    for (const image of facts.images) if (!image.ok) found.push(`image not decoded: ${image.src}...`);
    for (const ref of facts.refs) {
      if (ref.startsWith('#') || ref.startsWith('data:')) continue;
      if (/^[a-z][a-z0-9+.-]*:/i.test(ref)) {
        found.push(`link leaves the report: ${ref}`);
        continue;
      }
      const target = path.resolve(pageDir, decodeURIComponent(ref.split('#')[0]));
      if (!fs.existsSync(target)) found.push(`link to a missing file: ${ref}`);
    }
    for (const text of withPlot ? options.expect : []) {
      if (!facts.text.includes(text)) found.push(`the page does not show "${text}"`);
    }

    if (withPlot && options.plot) await checkPlots(page, found);

    const png = await page.screenshot({ path: screenshotPath, fullPage: true });
    const stats = await screenshotStatistics(browser, png);
    if (stats.colours < 16) found.push(`screenshot looks blank: ${stats.colours} distinct colours`);
    if (stats.inked < 0.02) found.push(`screenshot looks blank: ${(stats.inked * 100).toFixed(2)}% non-white pixels`);
    console.log(`check_report: ${path.relative(process.cwd(), pagePath)}: ${facts.height} px high, ` +
                `${facts.images.length} images, screenshot ${stats.width}x${stats.height} with ${stats.colours} colours, ` +
                `${(stats.inked * 100).toFixed(1)}% inked -> ${screenshotPath}`);
  } finally {
    await context.close();
  }
  for (const f of found) problems.push(`${path.relative(process.cwd(), pagePath)}: ${f}`);
}

async function main() {
  const options = parseArgs(process.argv.slice(2));
  const problems = [];
  // One browser for every page (--also: more pages, each with its own screenshot beside
  // the first, OUT_1.png, OUT_2.png, ...; --plot and --expect apply to the first page).
  const browser = await chromium.launch({ executablePath: kChromium, args: ['--no-sandbox'] });
  try {
    await checkPage(browser, path.resolve(options.page), options.screenshot, options, true, problems);
    for (let i = 0; i < options.also.length; ++i) {
      const shot = options.screenshot.replace(/(\.png)?$/, `_${i + 1}.png`);
      await checkPage(browser, path.resolve(options.also[i]), shot, options, false, problems);
    }
  } finally {
    await browser.close();
  }
  if (problems.length) {
    console.error(`check_report: FAIL: ${options.page}${options.also.length ? ` (+${options.also.length} pages)` : ''}`);
    for (const p of problems) console.error(`  - ${p}`);
    process.exit(1);
  }
  console.log('check_report: ok');
}

main().catch((error) => {
  console.error(`check_report: FAIL: ${error.stack || error}`);
  process.exit(1);
});
