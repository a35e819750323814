#!/usr/bin/env python3
"""Probe through Python against `penumbra probe` on the same points (issue 14's target: Python
at least 90% of the CLI's points per second on 2 threads).

    PYTHONPATH=build /usr/bin/python3 bench/bench_python.py [--points 1000000] [--threads 2]

Points are spread uniformly over the floor of the scene (default vdb_scenes/default.json),
normals up, so most of them see a penumbra or an umbra. Three runs, alternated over --rounds
blocks of the points and each timed on the probe work alone (the scene is loaded outside the
timing; for the CLI, what a run on one point costs is subtracted from each run):
  - Python: Scene.probe(points, normals, threads=T);
  - CLI, one process (its probe runs on one thread);
  - CLI, T processes side by side, each on a slice of the points: the CLI on T cores.
Prints points per second of each and the ratios. A benchmark, not a test: it never fails on a
time, only when the two disagree on a value.
"""
import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

import penumbra

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def write_csv(path, points, normals):
    np.savetxt(path, np.hstack([points, normals]), fmt="%.17g", delimiter=",",
               header="x,y,z,nx,ny,nz", comments="")


def cpu_seconds(who):
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def run_cli(cli, scene, inputs, outputs):
    """Runs one `penumbra probe` per input file, side by side; returns the wall time and the
    processor time of the processes."""
    start, cpu = time.perf_counter(), cpu_seconds(resource.RUSAGE_CHILDREN)
    procs = []
    for src, dst in zip(inputs, outputs):
        with open(src) as fin, open(dst, "w") as fout:
            procs.append(subprocess.Popen([cli, "probe", scene], stdin=fin, stdout=fout))
    for p in procs:
        if p.wait() != 0:
            sys.exit(f"penumbra probe failed with code {p.returncode}")
    return np.array([time.perf_counter() - start, cpu_seconds(resource.RUSAGE_CHILDREN) - cpu])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--scene", default=os.path.join(ROOT, "vdb_scenes", "default.json"))
    ap.add_argument("--cli", default=os.path.join(os.path.dirname(penumbra.__file__), "penumbra"))
    ap.add_argument("--extent", type=float, default=2.0, help="points in [-E, E]^2 on the floor")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=10, help="alternations of the three runs")
    a = ap.parse_args()

    rng = np.random.default_rng(a.seed)
    n, t = a.points, a.threads
    points = np.zeros((n, 3))
    points[:, :2] = rng.uniform(-a.extent, a.extent, size=(n, 2))
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    load = os.getloadavg()[0]
    print(f"{n} points, {t} threads, scene {os.path.relpath(a.scene, ROOT)}, "
          f"{os.cpu_count()} cores, load average {load:.2f} at the start")

    scene = penumbra.Scene.load(a.scene)
    scene.probe(points[:1000], normals[:1000], threads=t)  # warm: far fields, arena
    py_seconds = py_cpu = 0.0
    cli1, clit = np.zeros(2), np.zeros(2)  # wall, processor seconds
    rays = 0
    with tempfile.TemporaryDirectory() as tmp:
        # What a run costs besides its points: start, scene load, the far-field companions
        # built on the first clearance query. Measured on one point, alone and T side by side.
        one = os.path.join(tmp, "one_point.csv")
        write_csv(one, points[:1], normals[:1])
        startup1 = np.median([run_cli(a.cli, a.scene, [one], [os.path.join(tmp, "e.csv")])
                              for _ in range(3)], axis=0)
        startupt = np.median([run_cli(a.cli, a.scene, [one] * t,
                                      [os.path.join(tmp, f"e{k}.csv") for k in range(t)])
                              for _ in range(3)], axis=0)
        # Rounds alternate the three runs, so that a load that comes and goes on a shared
        # machine weighs on each alike.
        for r, block in enumerate(np.array_split(np.arange(n), a.rounds)):
            p, nrm = points[block], normals[block]
            start, cpu = time.perf_counter(), cpu_seconds(resource.RUSAGE_SELF)
            result = scene.probe(p, nrm, threads=t)
            py_seconds += time.perf_counter() - start
            py_cpu += cpu_seconds(resource.RUSAGE_SELF) - cpu
            rays += int(result["shadow_rays"].sum())

            whole = os.path.join(tmp, "all.csv")
            write_csv(whole, p, nrm)
            one_out = os.path.join(tmp, "one.csv")
            cli1 += run_cli(a.cli, a.scene, [whole], [one_out]) - startup1
            slices, outs = [], []
            for k, part in enumerate(np.array_split(np.arange(len(block)), t)):
                slices.append(os.path.join(tmp, f"part{k}.csv"))
                outs.append(os.path.join(tmp, f"out{k}.csv"))
                write_csv(slices[-1], p[part], nrm[part])
            clit += run_cli(a.cli, a.scene, slices, outs) - startupt

            # The same numbers (the CLI writes 12 significant digits).
            cli_ff = np.loadtxt(one_out, delimiter=",", skiprows=1, usecols=3, ndmin=1)
            py_ff = np.array(["%.12g" % v for v in result["form_factor"]], float)
            if not np.array_equal(cli_ff, py_ff):
                sys.exit(f"round {r}: Python and the CLI disagree on the form factors")

    rates = {"python": n / py_seconds, "cli1": n / cli1[0], "cli": n / clit[0]}
    per_cpu = {"python": n / py_cpu, "cli1": n / cli1[1], "cli": n / clit[1]}
    rows = [("python", f"Python, Scene.probe(threads={t})", py_seconds, py_cpu),
            ("cli1", "CLI, one process (1 thread)", *cli1),
            ("cli", f"CLI, {t} processes side by side", *clit)]
    print(f"  {'':34s} {'wall s':>8s} {'points/s':>10s} {'cpu s':>8s} {'points/cpu s':>12s}")
    for key, name, wall, cpu in rows:
        print(f"  {name:34s} {wall:8.2f} {rates[key]:10.0f} {cpu:8.2f} {per_cpu[key]:12.0f}")
    print(f"  a CLI run's cost besides its points (subtracted from each): {startup1[0]:.2f} s "
          f"alone, {startupt[0]:.2f} s for {t} side by side")
    print(f"Python / CLI on {t} processes: {rates['python'] / rates['cli']:.2f} in points per "
          f"second (target >= 0.90), {per_cpu['python'] / per_cpu['cli']:.2f} in points per "
          f"processor second; Python / CLI in one process: "
          f"{rates['python'] / rates['cli1']:.2f}")
    print(f"shadow rays per point {rays / n:.1f}; load average {os.getloadavg()[0]:.2f} at the "
          f"end (on a shared machine, points per processor second are the steadier figure)")

if __name__ == "__main__":
    main()
