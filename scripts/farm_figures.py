#!/usr/bin/env python3
"""The bake farm's closing-note figures (issue 8), each on a fresh farm on this machine:

1. the maze with its pillars baked by 1 and by 2 workers (each worker `--threads 1`, so two
   workers stand for two one-core machines), wall time from submission to success;
2. the bytes that crossed NATS for each bake: the server's `/varz` in_bytes + out_bytes
   (monitoring on `-m PORT`) after the bake minus before it;
3. the redelivery delay: a worker is SIGKILLed right after it starts a unit, and the time until
   another worker starts the same unit is measured (it is bounded by the consumers' ack wait).

Needs: `nats-server` on PATH (or /usr/sbin), a release build of `lightfarm`.
Usage: scripts/farm_figures.py [--bin target/release/lightfarm] [--texels 8] [--rays 1024]
"""

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def http(method, url, body=None):
    data = body if body is None or isinstance(body, bytes) else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, method=method)
    if body is not None and not isinstance(body, bytes):
        request.add_header("content-type", "application/json")
    with urllib.request.urlopen(request) as response:
        return json.loads(response.read() or b"null")


def wait_for(predicate, timeout, step=0.02):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    return None


class Farm:
    """nats-server, one `serve --farm` replica and `workers` workers, on a fresh directory."""

    def __init__(self, binary, workers):
        self.dir = tempfile.mkdtemp(prefix="lightfarm-figures-")
        self.processes = []
        nats = shutil.which("nats-server") or "/usr/sbin/nats-server"
        self.nats_port, self.monitor_port, self.http_port = free_port(), free_port(), free_port()
        self.spawn([nats, "-js", "-a", "127.0.0.1", "-p", str(self.nats_port),
                    "-m", str(self.monitor_port), "-sd", os.path.join(self.dir, "nats")], "nats")
        wait_for(lambda: self.varz(), 30)
        url = f"nats://127.0.0.1:{self.nats_port}"
        self.base = f"http://127.0.0.1:{self.http_port}"
        self.spawn([binary, "serve", "--addr", f"127.0.0.1:{self.http_port}", "--farm", url,
                    "--data", os.path.join(self.dir, "serve")], "serve")
        wait_for(lambda: self.healthy(), 60)
        self.workers = []
        for i in range(workers):
            log = os.path.join(self.dir, f"worker-{i}.log")
            process = self.spawn([binary, "worker", "--farm", url, "--threads", "1",
                                  "--cache", os.path.join(self.dir, f"worker-{i}")], log)
            self.workers.append((process, log))
        for _, log in self.workers:
            wait_for(lambda: ": ready" in open(log).read(), 60)

    def spawn(self, argv, log):
        path = log if "/" in log else os.path.join(self.dir, log + ".log")
        process = subprocess.Popen(argv, stdout=open(path, "w"), stderr=subprocess.STDOUT)
        self.processes.append(process)
        return process

    def varz(self):
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{self.monitor_port}/varz") as r:
                return json.loads(r.read())
        except OSError:
            return None

    def healthy(self):
        try:
            with urllib.request.urlopen(self.base + "/healthz"):
                return True
        except OSError:
            return False

    def stored_bytes(self, stream):
        with urllib.request.urlopen(
                f"http://127.0.0.1:{self.monitor_port}/jsz?streams=true") as r:
            jsz = json.loads(r.read())
        for account in jsz.get("account_details", []):
            for detail in account.get("stream_detail", []):
                if detail["name"] == stream:
                    return detail["state"]["bytes"]
        return 0

    def nats_bytes(self):
        v = self.varz()
        return v["in_bytes"] + v["out_bytes"]

    def submit_maze(self, settings):
        scene = open(os.path.join(ROOT, "scenes/maze/scene.json"), "rb").read()
        scene_id = http("POST", self.base + "/v1/scenes", scene)["id"]
        return http("POST", self.base + "/v1/bakes", {"scene": scene_id, "settings": settings})["id"]

    def wait_final(self, bake, timeout=3600):
        def final():
            status = http("GET", f"{self.base}/v1/bakes/{bake}")
            return status if status["state"] in ("succeeded", "failed", "cancelled") else None
        return wait_for(final, timeout, step=0.1)

    def close(self):
        for p in self.processes:
            if p.poll() is None:
                p.kill()
            p.wait()
        shutil.rmtree(self.dir, ignore_errors=True)


def started_units(log):
    """(unit, job, delivery) of every "started unit" line so far."""
    found = []
    for line in open(log).read().splitlines():
        if ": started unit " in line:
            rest = line.split(": started unit ", 1)[1]
            unit, rest = rest.split(" of job ", 1)
            job = rest.split()[0]
            found.append((unit, job))
    return found


def timed_bake(binary, workers, settings):
    farm = Farm(binary, workers)
    try:
        before = farm.nats_bytes()
        started = time.monotonic()
        bake = farm.submit_maze(settings)
        status = farm.wait_final(bake)
        seconds = time.monotonic() - started
        crossed = farm.nats_bytes() - before
        assert status["state"] == "succeeded", status
        operators = farm.stored_bytes("OBJ_lightfarm_operators")
        stages = ", ".join(f"{s['stage']} {s['seconds']:.1f} s" for s in status["stages"])
        return seconds, crossed, status["bundle_bytes"], operators, stages
    finally:
        farm.close()


def redelivery(binary, settings):
    farm = Farm(binary, 2)
    try:
        bake = farm.submit_maze(settings)
        hit = wait_for(lambda: next(((i, u) for i, (_, log) in enumerate(farm.workers)
                                     for u in started_units(log)), None), 120, step=0.005)
        victim, (unit, job) = hit
        farm.workers[victim][0].send_signal(signal.SIGKILL)
        killed = time.monotonic()
        other_log = farm.workers[1 - victim][1]
        again = wait_for(lambda: (unit, job) in started_units(other_log), 120, step=0.005)
        delay = time.monotonic() - killed if again else None
        status = farm.wait_final(bake)
        return unit, delay, status["state"]
    finally:
        farm.close()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bin", default=os.path.join(ROOT, "target/release/lightfarm"))
    parser.add_argument("--texels", type=int, default=8)
    parser.add_argument("--rays", type=int, default=1024)
    args = parser.parse_args()
    settings = {"texels_per_face": args.texels, "rays_per_texel": args.rays}
    print(f"maze with pillars, settings {json.dumps(settings)}, every worker --threads 1, "
          f"{os.cpu_count()} cores on this machine, load average {os.getloadavg()[0]:.1f}")
    for workers in (1, 2):
        seconds, crossed, bundle, operators, stages = timed_bake(args.bin, workers, settings)
        print(f"{workers} worker(s): {seconds:.1f} s ({stages}); {crossed / 1e6:.1f} MB across "
              f"NATS (operator files stored {operators / 1e6:.1f} MB, bundle "
              f"{bundle / 1e6:.2f} MB)")
    unit, delay, state = redelivery(args.bin, settings)
    if delay is None:
        print(f"redelivery: unit {unit} was not started again (it had finished); bake {state}")
    else:
        print(f"redelivery: unit {unit} started again {delay:.1f} s after its worker's SIGKILL; "
              f"bake {state}")


if __name__ == "__main__":
    sys.exit(main())
