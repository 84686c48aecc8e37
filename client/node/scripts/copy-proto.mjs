// Copies the repository's API definition into the package, so that a packed
// or installed copy carries the proto it loads at run time. The copy is
// generated (client/node/.gitignore): proto/ in the repository is the one
// source. Outside the repository (an unpacked tarball) the copy it already
// carries is kept.
import { copyFileSync, existsSync, mkdirSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(dirname(fileURLToPath(import.meta.url)));
const source = join(here, "..", "..", "proto", "geodesic", "v1", "geodesic.proto");
const target = join(here, "proto", "geodesic", "v1", "geodesic.proto");
if (existsSync(source)) {
  mkdirSync(dirname(target), { recursive: true });
  copyFileSync(source, target);
} else if (!existsSync(target)) {
  console.error(`copy-proto: neither ${source} nor ${target} exists`);
  process.exit(1);
}
