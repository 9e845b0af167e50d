"""The hscloc tools, the trained small city of the test suite's fixture
(tests/make_trained_city.sh) and `hscloc serve` on a free loopback port."""

from __future__ import annotations

import queue
import signal
import subprocess
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import pytest


@dataclass(frozen=True)
class Tools:
    hscloc: Path
    hscloc_client: Path


@dataclass(frozen=True)
class City:
    """The trained small city: city/ (model, features, queries) and map/ (the trained bundle)."""

    root: Path

    @property
    def map(self) -> Path:
        return self.root / "map"

    @property
    def features(self) -> Path:
        return self.root / "city" / "features.h5"

    @property
    def day_queries(self) -> Path:
        return self.root / "city" / "queries" / "day_time_queries_with_intrinsics.txt"

    @property
    def night_queries(self) -> Path:
        return self.root / "city" / "queries" / "night_time_queries_with_intrinsics.txt"


@contextmanager
def serve(tools: Tools, map_dir: Path, log: Path, *arguments: object) -> Iterator[str]:
    """Runs `hscloc serve` on a free loopback port and yields its endpoint; stops it with SIGTERM
    and checks that it drained and exited 0."""
    with open(log, "w") as log_file:
        server = subprocess.Popen(
            [str(tools.hscloc), "serve", "--map", str(map_dir), "--bind", "tcp://127.0.0.1:0",
             "--admin-bind", "tcp://127.0.0.1:0", "--workers", "2", *map(str, arguments)],
            stdout=subprocess.PIPE, stderr=log_file, text=True)
    lines: queue.Queue = queue.Queue()

    def read_lines() -> None:
        for line in server.stdout:
            lines.put(line)
        lines.put(None)  # the server closed its output: it exited

    threading.Thread(target=read_lines, daemon=True).start()
    try:
        endpoint = ""
        while not endpoint:
            try:
                line = lines.get(timeout=120)
            except queue.Empty:
                pytest.fail(f"hscloc serve did not start within 120 s: {log.read_text()}")
            if line is None:
                pytest.fail(f"hscloc serve exited before listening: {log.read_text()}")
            if line.startswith("listening on "):
                endpoint = line.split()[-1]
        yield endpoint
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            status = server.wait(timeout=60)
        except subprocess.TimeoutExpired:
            server.kill()
            raise
    assert status == 0, f"hscloc serve exited {status}: {log.read_text()}"

