#!/usr/bin/env python3
"""Runs a command and measures its wall time and peak memory: the largest sum of the resident
sets of the command and all its descendants at once (sampled every 20 ms from /proc), which
is what the machine must hold, and the kernel's peak of the largest single process
(getrusage of the children, exact but per process). Writes one JSON object to the file named
by --json-out and passes the command's output through.

Usage: peak_rss.py --json-out FILE -- COMMAND [ARGS...]
"""
import json
import os
import resource
import subprocess
import sys
import time


def descendants(root):
    """PIDs of root and every process below it."""
    children = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        # The command name may hold spaces and parentheses: fields follow the last ')'.
        ppid = int(stat[stat.rfind(")") + 2 :].split()[1])
        children.setdefault(ppid, []).append(int(d))
    out, todo = [], [root]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def rss_bytes(pid):
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, IndexError, ValueError):
        return 0


def main():
    args = sys.argv[1:]
    if len(args) < 4 or args[0] != "--json-out" or args[2] != "--":
        sys.exit("usage: peak_rss.py --json-out FILE -- COMMAND [ARGS...]")
    out_path, cmd = args[1], args[3:]
    start = time.monotonic()
    proc = subprocess.Popen(cmd)
    peak = 0
    while proc.poll() is None:
        peak = max(peak, sum(rss_bytes(p) for p in descendants(proc.pid)))
        time.sleep(0.02)
    wall = time.monotonic() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    with open(out_path, "w") as f:
        json.dump(
            {
                "exit_code": proc.returncode,
                "wall_s": round(wall, 3),
                "peak_tree_rss_bytes": peak,
                "peak_process_rss_bytes": usage.ru_maxrss * 1024,
                "user_s": round(usage.ru_utime, 3),
                "system_s": round(usage.ru_stime, 3),
            },
            f,
        )
    sys.exit(proc.returncode)


if __name__ == "__main__":
    main()
