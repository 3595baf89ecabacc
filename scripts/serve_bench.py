#!/usr/bin/env python3
"""Times `matedit serve` from upload to result over HTTP: one user without and with Eq. 6, then
several users at once (every edit must finish, none lost), then more users than the queue holds
(the surplus is refused with 503 and nothing else is lost). Prints a Markdown table.

Usage (after `cargo build --release -p matedit-edit`): scripts/serve_bench.py MODEL PHOTO [MASK] [--users 6] [--runs 5]
       (PHOTO's alpha is the mask when MASK is not given)
"""
import argparse, json, os, re, signal, statistics, subprocess, sys, threading, time, urllib.error, urllib.request, uuid


def multipart(fields):
    boundary = uuid.uuid4().hex
    body = bytearray()
    for name, filename, data in fields:
        body += f"--{boundary}\r\n".encode()
        if filename:
            body += f'Content-Disposition: form-data; name="{name}"; filename="{filename}"\r\n\r\n'.encode()
        else:
            body += f'Content-Disposition: form-data; name="{name}"\r\n\r\n'.encode()
        body += data + b"\r\n"
    body += f"--{boundary}--\r\n".encode()
    return bytes(body), f"multipart/form-data; boundary={boundary}"


def request(base, path, body=None, ctype=None):
    req = urllib.request.Request(base + path, data=body, method="POST" if body is not None else "GET")
    if ctype:
        req.add_header("Content-Type", ctype)
    if body is not None:
        req.add_header("x-matedit-page", "1")  # what the page sends with every change
    try:
        with urllib.request.urlopen(req, timeout=600) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def one_edit(base, fields):
    """Seconds from the upload's start to the result being available, or None when refused."""
    body, ctype = multipart(fields)
    t0 = time.perf_counter()
    status, out = request(base, "/api/edit", body, ctype)
    if status == 503:
        return None, "refused"
    if status != 202:
        raise SystemExit(f"upload refused ({status}): {out[:300]!r}")
    url = json.loads(out)["url"]
    while True:
        s, b = request(base, url)
        v = json.loads(b)
        if v["state"] == "done":
            # The page shows the composite next: fetch it as the page does.
            s2, png = request(base, f"{url}/files/edited.png")
            assert s2 == 200 and png.startswith(b"\x89PNG")
            return time.perf_counter() - t0, "done"
        if v["state"] in ("failed", "cancelled"):
            raise SystemExit(f"edit {v['state']}: {v.get('error')}")
        time.sleep(0.05)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model")
    ap.add_argument("photo")
    ap.add_argument("mask", nargs="?")
    ap.add_argument("--users", type=int, default=6)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--queue", type=int, default=8)
    ap.add_argument("--material", default="library:gold-polished")
    ap.add_argument("--binary", default="target/release/matedit")
    a = ap.parse_args()
    photo = open(a.photo, "rb").read()
    fields = [("photo", os.path.basename(a.photo), photo), ("material", None, a.material.encode())]
    if a.mask:
        fields.append(("mask", os.path.basename(a.mask), open(a.mask, "rb").read()))
    server = subprocess.Popen([a.binary, "serve", "--model", a.model, "--port", "0", "--queue", str(a.queue)],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        line = server.stdout.readline()
        m = re.search(r"http://[\d.:]+", line)
        if not m:
            raise SystemExit(f"the server did not start: {line!r}")
        base = m.group(0)
        one_edit(base, fields)  # warm-up: the material's fit, first allocations
        rows = []
        plain = [one_edit(base, fields)[0] for _ in range(a.runs)]
        rows.append(("1 user, no Eq. 6", a.runs, statistics.median(plain), max(plain), 0))
        opt = fields + [("optimize", None, b"on")]
        eq6 = [one_edit(base, opt)[0] for _ in range(max(1, a.runs // 2))]
        rows.append(("1 user, Eq. 6", len(eq6), statistics.median(eq6), max(eq6), 0))
        for users in (a.users, a.queue + 1 + a.users):
            results = [None] * users
            def go(i):
                results[i] = one_edit(base, fields)
            threads = [threading.Thread(target=go, args=(i,)) for i in range(users)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            times = [r[0] for r in results if r[1] == "done"]
            refused = sum(1 for r in results if r[1] == "refused")
            assert len(times) + refused == users, "an edit was lost"
            rows.append((f"{users} users at once (queue {a.queue})", len(times), statistics.median(times), max(times), refused))
        print(f"`{' '.join(sys.argv)}`\n")
        print("| load | edits done | median s upload→result | max s | refused (503) |")
        print("|---|---:|---:|---:|---:|")
        for name, n, med, mx, ref in rows:
            print(f"| {name} | {n} | {med:.2f} | {mx:.2f} | {ref} |")
    finally:
        server.send_signal(signal.SIGINT)  # lets the server remove its work folder
        server.wait()


if __name__ == "__main__":
    main()
