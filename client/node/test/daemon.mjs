// The tests' daemon: geodesicd serve on 127.0.0.1, port 0, the port read
// back from --port-file, every wait bounded, and the daemon stopped however
// the test process ends. A SIGKILLed test process runs no exit handler, so
// the daemon runs under a small shell that also kills it when the test's
// end of a pipe closes, which the kernel does for a process however it dies.
import { spawn } from "node:child_process";
import { closeSync, existsSync, openSync, readFileSync, writeFileSync } from "node:fs";
import { join } from "node:path";
import { setTimeout as sleep } from "node:timers/promises";

const WATCHDOG = `
exec 3<&0
"$@" </dev/null 3<&- &
d=$!
echo "$d"
( read -r _ <&3; kill "$d" 2>/dev/null ) &
w=$!
wait "$d"
rc=$?
kill "$w" 2>/dev/null
exit "$rc"
`;

const running = new Set();
process.on("exit", () => {
  for (const pid of running) {
    try { process.kill(pid, "SIGKILL"); } catch { /* gone already */ }
  }
});

let starts = 0;

/** Starts `BIN/geodesicd serve` with `args` in `work`; resolves { port, stop(), log }.
 * tokens: the daemon requires one of them on every call. */
export async function startDaemon(bin, work, args, { tokens, timeoutMs = 60000 } = {}) {
  const n = ++starts;
  const portFile = join(work, `ports.${n}.json`);
  const log = join(work, `daemon.${n}.log`);
  const command = [join(bin, "geodesicd"), "serve", "--listen", "127.0.0.1:0",
    "--port-file", portFile, "--drain-seconds", "1", ...args];
  if (tokens) {
    const tokenFile = join(work, `tokens.${n}`);
    writeFileSync(tokenFile, tokens.map((t) => `${t}\n`).join(""));
    command.push("--auth-token-file", tokenFile);
  }
  const logFd = openSync(log, "w");
  const shell = spawn("/bin/sh", ["-c", WATCHDOG, "sh", ...command],
    { stdio: ["pipe", "pipe", logFd] });
  closeSync(logFd);
  let exited = null;
  const exit = new Promise((resolve) => shell.on("exit", (code, signal) => {
    exited = code ?? signal;
    resolve();
  }));
  const pid = await new Promise((resolve, reject) => {
    shell.stdout.once("data", (data) => resolve(Number.parseInt(String(data), 10)));
    shell.once("error", reject);
  });
  running.add(pid);
  const tail = () => (existsSync(log) ? readFileSync(log, "utf8").slice(-4000) : "");
  const stop = async () => {
    if (exited === null) {
      shell.stdin.end();
      // Timers that do not keep the test process alive once all is done.
      const stopped = await Promise.race([exit.then(() => true),
        sleep(20000, false, { ref: false })]);
      if (!stopped) {
        try { process.kill(pid, "SIGKILL"); } catch { /* gone already */ }
        await Promise.race([exit, sleep(5000, undefined, { ref: false })]);
      }
    }
    running.delete(pid);
  };
  const deadline = Date.now() + timeoutMs;
  while (!existsSync(portFile)) {
    if (exited !== null || Date.now() > deadline) {
      await stop();
      throw new Error(`geodesicd ${exited !== null ? `exited (${exited})` : "wrote no port file"}` +
        ` before listening:\n${tail()}`);
    }
    await sleep(20);
  }
  // The daemon writes the file by rename: once there, it is whole.
  const ports = JSON.parse(readFileSync(portFile, "utf8"));
  return { port: ports.grpc, pid, stop, log: tail };
}
