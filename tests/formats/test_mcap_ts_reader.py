"""A log written by hystbench, read by the reference TypeScript reader (@mcap/core, what Foxglove
uses): the summary, the JSON schemas, the metadata and the base64 samples all decode.

Needs node and npm; the packages are installed once into a cache folder under the system temp
dir (bounded: 120 s), and the test is skipped, with the reason, when that is not possible."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from hystbench.acquisition.record import record_log
from hystbench.formats.mcaplog import iter_blocks, iter_log, log_metadata
from hystbench.acquisition.sources import SyntheticSource

PACKAGES = ["@mcap/core@2", "@foxglove/wasm-zstd@1"]

READER = r"""
import { McapIndexedReader } from "@mcap/core";
import { createRequire } from "node:module";
import { open } from "node:fs/promises";
const require = createRequire(import.meta.url);
const zstd = require("@foxglove/wasm-zstd");
await zstd.isLoaded;
const fh = await open(process.argv[2], "r");
const readable = {
  size: async () => BigInt((await fh.stat()).size),
  read: async (offset, size) => {
    const buf = Buffer.alloc(Number(size));
    await fh.read(buf, 0, Number(size), Number(offset));
    return new Uint8Array(buf.buffer, buf.byteOffset, buf.byteLength);
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: { zstd: (buf, size) => zstd.decompress(buf, Number(size)) },
});
const out = { profile: reader.header.profile, topics: {}, schemas: {}, metadata: {}, raw: [] };
for (const ch of reader.channelsById.values()) {
  const s = reader.schemasById.get(ch.schemaId);
  out.schemas[ch.topic] = [ch.messageEncoding, s.encoding, JSON.parse(new TextDecoder().decode(s.data)).title];
}
for await (const m of reader.readMetadata()) out.metadata[m.name] = JSON.parse(m.metadata.get("json"));
for await (const msg of reader.readMessages({ validateCrcs: true })) {
  const topic = reader.channelsById.get(msg.channelId).topic;
  out.topics[topic] = (out.topics[topic] ?? 0) + 1;
  const obj = JSON.parse(new TextDecoder().decode(msg.data));
  if (topic === "/raw" && out.raw.length < 3) {
    const ch = obj.channels[0];
    const bytes = Buffer.from(ch.data, "base64");
    const x = new Float32Array(bytes.buffer, bytes.byteOffset, bytes.byteLength / 4);
    out.raw.push({ first_index: obj.first_index, name: ch.name, n: x.length, head: Array.from(x.slice(0, 5)) });
  }
}
await fh.close();
console.log(JSON.stringify(out));
"""


@pytest.fixture(scope="module")
def node_reader() -> Path:
    node, npm = shutil.which("node"), shutil.which("npm")
    if not node or not npm:
        pytest.skip("node/npm not installed: the TypeScript reader check needs them")
    folder = Path(tempfile.gettempdir()) / "hystbench-mcap-ts-reader"
    folder.mkdir(exist_ok=True)
    if not (folder / "node_modules" / "@mcap" / "core").is_dir() or \
            not (folder / "node_modules" / "@foxglove" / "wasm-zstd").is_dir():
        (folder / "package.json").write_text('{"name": "hystbench-mcap-check", "private": true}\n')
        try:
            proc = subprocess.run([npm, "install", "--no-audit", "--no-fund", "--silent", *PACKAGES], cwd=folder,
                                  capture_output=True, text=True, timeout=120)
        except subprocess.TimeoutExpired:
            pytest.skip(f"npm install {' '.join(PACKAGES)} took more than 120 s")
        if proc.returncode != 0:
            pytest.skip(f"npm install {' '.join(PACKAGES)} failed: {(proc.stderr or proc.stdout)[-400:]}")
    script = folder / "read_log.mjs"
    script.write_text(READER)
    return script


def test_typescript_reader_decodes_our_log(node_reader: Path, tmp_path: Path) -> None:
    log = tmp_path / "ts.mcap"
    src = SyntheticSource(fs_hz=100_000.0, block_samples=2000, pace="max", duration_s=0.3)
    record_log(src, log)
    proc = subprocess.run(["node", str(node_reader), str(log)], cwd=node_reader.parent, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout)
    assert got["profile"] == "hystbench"
    assert got["topics"] == dict(Counter(m.topic for m in iter_log(log)))
    for topic, (msg_enc, schema_enc, title) in got["schemas"].items():
        assert (msg_enc, schema_enc) == ("json", "jsonschema") and title.startswith("hystbench.")
    assert got["metadata"]["recording"] == log_metadata(log)["recording"]
    first = list(iter_blocks(log))[:3]
    for js, b in zip(got["raw"], first):
        x = b.channels[js["name"]]
        assert js["first_index"] == b.first_index and js["n"] == b.n
        assert js["head"] == [float(v) for v in np.asarray(x[:5], dtype=np.float64)]
