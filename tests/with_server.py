#!/usr/bin/env python3
"""Runs a command beside a real progskin-server on loopback (the C, Python
and C# binding tests; ctest registers them in tests/ and bindings/).

    with_server.py --server PATH/progskin-server [--server-arg ARG ...] -- COMMAND ...

Starts the server with TLS (its self-signed pair made in a temporary
--tls-dir), sealed datagrams, an ephemeral port on 127.0.0.1 and the default
scene, waits for its listening line, then runs COMMAND with these
environment variables set:

    PROGSKIN_HOST       127.0.0.1
    PROGSKIN_PORT       the server's TCP port
    PROGSKIN_PIN        the SHA-256 of its certificate (hex), for pin_sha256
    PROGSKIN_INSTANCES  the instances of its scene
    PROGSKIN_CACHE      an empty asset cache directory for the clients

and exits with COMMAND's exit status (the server is stopped either way; 1
when the server does not start).
"""
import argparse
import os
import re
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time


def start_server(server, extra, tmp):
    cmd = [server, "--port", "0", "--bind", "127.0.0.1", "--tls-dir", os.path.join(tmp, "tls"),
           "--cache", os.path.join(tmp, "server-cache"), "--duration", "300"] + extra
    err_path = os.path.join(tmp, "server.err")  # a file: a full pipe would stall the server
    with open(err_path, "w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
    info, lines = {}, []
    q = queue.Queue()  # stdout lines, read by a thread (select would miss lines already buffered)
    threading.Thread(target=lambda: [q.put(l) for l in proc.stdout] + [q.put(None)], daemon=True).start()
    deadline = time.monotonic() + 120  # the first run builds the progressive assets
    while "port" not in info:
        try:
            line = q.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            break
        if line is None:
            break
        lines.append(line)
        m = re.search(r"TLS certificate sha256 ([0-9A-Fa-f:]+)", line)
        if m:
            info["pin"] = m.group(1)
        m = re.search(r"listening on TCP (\d+), UDP \d+, (\d+) instances", line)
        if m:
            info["port"], info["instances"] = m.group(1), m.group(2)
    if "port" not in info:
        proc.kill()
        proc.wait()
        with open(err_path) as err:
            sys.stderr.write("with_server: progskin-server did not start:\n" + "".join(lines) + err.read())
        return None, None
    return proc, info


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", required=True, help="the progskin-server executable")
    ap.add_argument("--server-arg", action="append", default=[], help="one more server argument (repeatable)")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND ...")
    a = ap.parse_args()
    command = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not command:
        ap.error("no command after --")
    tmp = tempfile.mkdtemp(prefix="progskin-with-server-")
    proc = None
    try:
        proc, info = start_server(a.server, a.server_arg, tmp)
        if not proc:
            return 1
        env = dict(os.environ, PROGSKIN_HOST="127.0.0.1", PROGSKIN_PORT=info["port"], PROGSKIN_PIN=info.get("pin", ""),
                   PROGSKIN_INSTANCES=info["instances"], PROGSKIN_CACHE=os.path.join(tmp, "client-cache"))
        os.makedirs(env["PROGSKIN_CACHE"])
        print("with_server: progskin-server on 127.0.0.1:%s, %s instances, TLS pin %s" %
              (info["port"], info["instances"], info.get("pin", "-")), flush=True)
        return subprocess.call(command, env=env)
    finally:
        if proc and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
