// Builds viewer/soma_view.html, the page template of `soma view`: esbuild
// bundles src/main.js with three.js (the versions pinned in
// package-lock.json) into one minified script; the script and src/style.css
// are inlined into src/index.html. The result is self-contained (no network)
// and holds the data placeholder once. It records the sha256 of its sources
// (`sources_hash`, the same value as tests/view/template_test.sh computes),
// so a test can tell a template that is older than its sources.
//
//   cd viewer && npm ci && node build.mjs        # or: npm run build
import { build } from 'esbuild';
import { createHash } from 'node:crypto';
import { readFileSync, readdirSync, writeFileSync, renameSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const root = dirname(fileURLToPath(import.meta.url));
const PLACEHOLDER = '__SOMA_VIEW_DATA__';

// sha256 over `sha256sum` lines ("<hex>  <path>\n") of the sources, in this
// order: build.mjs, package.json, package-lock.json, src/* (sorted).
export function sourcesHash() {
  const files = ['build.mjs', 'package.json', 'package-lock.json',
    ...readdirSync(join(root, 'src')).sort().map((f) => `src/${f}`)];
  const lines = files.map((f) => {
    const hex = createHash('sha256').update(readFileSync(join(root, f))).digest('hex');
    return `${hex}  ${f}\n`;
  });
  return createHash('sha256').update(lines.join('')).digest('hex');
}

const result = await build({
  entryPoints: [join(root, 'src/main.js')],
  bundle: true,
  minify: true,
  format: 'iife',
  target: ['es2020'],
  legalComments: 'none',
  write: false,
  logLevel: 'warning',
});
const js = result.outputFiles[0].text;
if (/<\/script/i.test(js)) throw new Error('the bundle contains "</script": it cannot be inlined');
if (js.includes(PLACEHOLDER)) throw new Error(`the bundle contains the data placeholder ${PLACEHOLDER}`);
const css = readFileSync(join(root, 'src/style.css'), 'utf8');
const three = JSON.parse(readFileSync(join(root, 'node_modules/three/package.json'), 'utf8')).version;
const esbuildVersion = JSON.parse(readFileSync(join(root, 'node_modules/esbuild/package.json'), 'utf8')).version;

let html = readFileSync(join(root, 'src/index.html'), 'utf8');
const replace = (marker, text) => {
  if (html.split(marker).length !== 2) throw new Error(`src/index.html must hold ${marker} once`);
  html = html.replace(marker, () => text);
};
replace('<!--SOMA_SOURCES-->',
  `<meta name="soma-viewer-build" content="sources_hash=${sourcesHash()} three=${three} esbuild=${esbuildVersion}">`);
replace('<!--SOMA_CSS-->', `<style>\n${css}</style>`);
replace('<!--SOMA_JS-->', `<script>${js}</script>`);
if (html.split(PLACEHOLDER).length !== 2) throw new Error(`the template must hold ${PLACEHOLDER} once`);

// `node build.mjs --out <file>` writes elsewhere (tests/view/template_test.sh
// rebuilds into a temporary file and compares).
const outArg = process.argv.indexOf('--out');
const out = outArg > 0 ? process.argv[outArg + 1] : join(root, 'soma_view.html');
writeFileSync(`${out}.tmp`, html);
renameSync(`${out}.tmp`, out);
console.log(`wrote ${out} (${html.length} bytes; three ${three}, esbuild ${esbuildVersion})`);
