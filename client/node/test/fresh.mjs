// The tests import the compiled package (dist/), which scripts/setup.sh
// builds: one older than a source it was built from would test the old
// code, so that fails here first, saying what to run. (A missing dist/ fails
// before this runs, naming dist/index.js.)
import { readdirSync, statSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const root = dirname(dirname(fileURLToPath(import.meta.url)));
const mtime = (path) => statSync(path).mtimeMs;
const hint = "run scripts/setup.sh (or npm ci && npm run build in client/node)";
// tsc writes every output on each build: index.js is as old as the build.
const built = mtime(join(root, "dist", "index.js"));
const newer = readdirSync(join(root, "src")).map((f) => join("src", f))
  .filter((f) => mtime(join(root, f)) > built);
if (newer.length > 0) {
  throw new Error(`client/node/dist is older than ${newer.join(", ")}: ${hint}`);
}
