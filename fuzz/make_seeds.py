#!/usr/bin/python3
"""Writes the generated seed files of fuzz/corpus/ (frames, registers, CSV,
HTTP) and copies the repo's TOML examples into the config and schedule
corpora. Run from anywhere; rerun after changing it. Crash inputs kept as
regression seeds (corpus/*/regress-*) are not touched."""
import os
import random
import shutil
import struct
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "fuzz" / "corpus"
HEADER = bytes([0xFE, 0x81, 0xFF, 0x55])
TOKEN = "fuzz-token-0123456789abcdef"  # http_fuzz.cpp's kToken


def crc32_mpeg2(data):
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7) if crc & 0x80000000 else crc << 1
            crc &= 0xFFFFFFFF
    return crc


def write(target, name, data):
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes(data if isinstance(data, bytes) else data.encode())


def clear(target):
    d = CORPUS / target
    if d.exists():
        for f in d.iterdir():
            if not f.name.startswith("regress-"):
                f.unlink()


# --- frame_parser: frame_parser_fuzz.cpp reads its input as a script
# (FuzzedDataProvider: op codes and lengths from the END of the input, raw
# bytes from the front). script() builds one: each chunk of `parts` is
# appended by a raw-bytes op (0, length), each int in `parts` sets a chunk
# boundary (op 4). The fuzzer mutates from there into the other ops.
def script(*parts):
    front, ops = b"", []
    for p in parts:
        if isinstance(p, int):
            ops += [4, p]
        else:
            for i in range(0, len(p), 64):
                piece = p[i:i + 64]
                front += piece
                ops += [0, len(piece)]
    return front + bytes(reversed(ops))


def frame(seq, gyro=(1e-5, -2e-5, 3e-5), accel=(0.0, 0.0, 1.0), status=0x77, temp=25):
    body = HEADER + struct.pack(">3f3fBBh", *gyro, *accel, status, seq, temp)
    return body + struct.pack(">I", crc32_mpeg2(body))


def frame_seeds():
    clear("frame_parser")
    rng = random.Random(7)
    noise = bytes(rng.randrange(256) for _ in range(20))
    bad = bytearray(frame(4))
    bad[10] ^= 0x01
    seeds = {
        "one-frame": script(frame(0)),
        "three-frames-split": script(7, frame(0) + frame(1) + frame(2), 36, 1),
        "seq-gap": script(frame(5) + frame(9)),
        "seq-wrap": script(frame(127) + frame(0)),
        "noise-then-frame": script(noise + frame(3)),
        "bad-crc-then-good": script(bytes(bad) + frame(5)),
        "header-prefix-tail": script(frame(6) + HEADER[:3]),
        "header-in-payload": script(frame(7, gyro=(struct.unpack(">f", HEADER)[0], 0, 0))),
        "lost-byte": script(frame(8)[:20] + frame(8)[21:] + frame(9)),
        "split-in-header": script(2, frame(10) + frame(11), 38),
    }
    for name, data in seeds.items():
        write("frame_parser", name, data)
    for i in range(4):
        write("frame_parser", f"random-{i}", bytes(rng.randrange(256) for _ in range(rng.randrange(40, 200))))


def register_seeds():
    clear("registers")
    rng = random.Random(11)
    write("registers", "zeros", bytes(64))
    write("registers", "ones", b"\xff" * 64)
    write("registers", "float-20C", struct.pack("<HH", 0, 0x41A0) * 16)
    for i in range(6):
        write("registers", f"random-{i}", bytes(rng.randrange(256) for _ in range(96)))


def toml_seeds():
    clear("config")
    for p in sorted((ROOT / "config").glob("*.toml")):
        write("config", p.name, p.read_bytes())
    write("config", "minimal.toml", "[station]\nname = \"fuzz\"\n")
    write("config", "custom-registers.toml",
          "[chamber]\nprofile = \"custom\"\n[chamber.registers.setpoint]\naddress = 10\n"
          "function = \"holding\"\ntype = \"int16\"\nscale = 0.1\n"
          "[chamber.registers.process_value]\naddress = 11\nfunction = \"input\"\n"
          "type = \"float32\"\nword_order = \"high-first\"\n")
    clear("schedule")
    for p in sorted((ROOT / "config" / "schedules").glob("*.toml")):
        write("schedule", p.name, p.read_bytes())
    for p in sorted((ROOT / "tests" / "schedules" / "bad").glob("*.toml")):
        write("schedule", "bad-" + p.name, p.read_bytes())


def csv_seeds():
    clear("csv")
    h = "t_s,rate_dph,top_c,side_c\n"
    write("csv", "simple.csv", h + "0,8,25,26\n1,9,25.5,26.5\n2,7,26,27\n")
    write("csv", "crlf-bom.csv", "\ufeff" + h.replace("\n", "\r\n") + "0,8,25,26\r\n1,9,25.5,26.5\r\n")
    write("csv", "extra-columns.csv", "note,side_c, t_s ,x,rate_dph,top_c\na,26,0,q,8,25\nb,26,1,q,9,25\n")
    write("csv", "fast-10hz.csv", h + "".join(f"{i / 10},{7.9 + (i % 3) * 0.1},{25 + i / 1000},{26 + i / 1000}\n" for i in range(40)))
    write("csv", "blank-lines.csv", "\n  \n" + h + "\n0,+1e-3,25,26\n\n1,-2e-3,25,26\n")
    write("csv", "bad-values.csv", h + "0,a,2,b\n1,1,2,3\n2,1,nan,3\n2,1,2\n")
    write("csv", "quote.csv", h + "0,\"1\",2,3\n")
    write("csv", "not-increasing.csv", h + "2,1,2,3\n1,1,2,3\n")
    write("csv", "header-only.csv", h)


def http(method, target, body=None, auth=True, extra=""):
    lines = [f"{method} {target} HTTP/1.1", "Host: localhost"]
    if auth:
        lines.append(f"Authorization: Bearer {TOKEN}")
    if extra:
        lines.append(extra)
    if body is not None:
        lines += ["Content-Type: application/json", f"Content-Length: {len(body.encode())}"]
    return "\r\n".join(lines) + "\r\n\r\n" + (body or "")


def http_seeds():
    clear("http")
    seeds = {
        "status": http("GET", "/api/v1/status", auth=False),
        "head-status": http("HEAD", "/api/v1/status", auth=False),
        "healthz": http("GET", "/healthz", auth=False),
        "metrics": http("GET", "/metrics", auth=False),
        "openapi": http("GET", "/api/v1/openapi.json", auth=False),
        "index": http("GET", "/", auth=False),
        "web-file": http("GET", "/web/app.js", auth=False),
        "queue-list": http("GET", "/api/v1/queue", auth=False),
        "queue-add": http("POST", "/api/v1/queue",
                          '{"schedule_toml":"[[step]]\\ntype = \\"hold\\"\\nsetpoint_c = 20\\nduration_min = 5\\n",'
                          '"source":"s.toml","ignore_failures":false}'),
        "queue-add-no-token": http("POST", "/api/v1/queue", '{"schedule_toml":""}', auth=False),
        "queue-add-bad-field": http("POST", "/api/v1/queue", '{"schedule":1}'),
        "queue-remove": http("DELETE", "/api/v1/queue/9"),
        "queue-move": http("POST", "/api/v1/queue/3/move", '{"position":2}'),
        "control-pause": http("POST", "/api/v1/control/pause", '{"reason":"lunch"}'),
        "control-abort": http("POST", "/api/v1/control/abort"),
        "control-unknown": http("POST", "/api/v1/control/explode"),
        "runs": http("GET", "/api/v1/runs", auth=False),
        "run": http("GET", "/api/v1/runs/12", auth=False),
        "run-events": http("GET", "/api/v1/runs/12/events", auth=False),
        "run-stats": http("GET", "/api/v1/runs/12/stats", auth=False),
        "run-fits": http("GET", "/api/v1/runs/7/fits", auth=False),
        "run-allan": http("GET", "/api/v1/runs/7/allan", auth=False),
        "fit": http("GET", "/api/v1/fits/9", auth=False),
        "exports": http("GET", "/api/v1/exports", auth=False),
        "samples": http("GET", "/api/v1/runs/4/samples?from=10&to=20.5&max_points=300", auth=False),
        "samples-percent": http("GET", "/api/v1/runs/4/samples?from=%2D5&max_points=20000", auth=False),
        "samples-bad": http("GET", "/api/v1/runs/4/samples?from=%zz&to=nan", auth=False),
        "wrong-method": http("PUT", "/api/v1/status"),
        "bad-id": http("GET", "/api/v1/runs/abc", auth=False),
        "wrong-token": http("POST", "/api/v1/control/stop", auth=False,
                            extra="Authorization: Bearer not-the-token"),
        "chunked": "POST /api/v1/control/stop HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + TOKEN
                   + "\r\nTransfer-Encoding: chunked\r\n\r\n4\r\n{\"re\r\n0\r\n\r\n",
        "stream": http("GET", "/api/v1/stream", auth=False),
        "queue-add-metadata": http("POST", "/api/v1/queue",
                                   '{"schedule_toml":"x","operator":"ana","comment":"a\\nb",'
                                   '"tags":["week-1","\\u00e9"],"duts":["17-0042"]}'),
        "run-edit": http("PATCH", "/api/v1/runs/12", '{"operator":"bo","tags":[],"duts":["a","b"]}'),
        "run-edit-empty": http("PATCH", "/api/v1/runs/12", '{}'),
        "duts": http("GET", "/api/v1/duts", auth=False),
        "dut": http("GET", "/api/v1/duts/SN%2017-0042", auth=False),
        "run-stats-filter": http("GET", "/api/v1/runs/12/stats?dut=17-0042&axis=z", auth=False),
        "samples-channel": http("GET", "/api/v1/runs/4/samples?dut=17-0042&channel=accel_x",
                                auth=False),
    }
    for name, text in seeds.items():
        write("http", name, text)


if __name__ == "__main__":
    frame_seeds()
    register_seeds()
    toml_seeds()
    csv_seeds()
    http_seeds()
    for d in sorted(CORPUS.iterdir()):
        print(f"{d.name}: {len(list(d.iterdir()))} files")
