"""Generates hscloc/hscloc_pb2.py from ../proto/hscloc.proto with protoc (Debian's
protobuf-compiler) while the package is built, so that the wire module is never checked in.
Everything else is in pyproject.toml."""

import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

PROTO = Path(__file__).resolve().parent.parent / "proto" / "hscloc.proto"


class BuildPyWithWire(build_py):
    def run(self) -> None:
        super().run()
        protoc = shutil.which("protoc")
        if protoc is None:
            raise RuntimeError("protoc is missing (Debian: apt-get install protobuf-compiler)")
        if not PROTO.is_file():
            raise RuntimeError(f"{PROTO} is missing: build from the hscloc repository")
        out = Path(self.build_lib) / "hscloc"
        out.mkdir(parents=True, exist_ok=True)
        subprocess.run([protoc, f"--python_out={out}", f"-I{PROTO.parent}", str(PROTO)],
                       check=True)


setup(cmdclass={"build_py": BuildPyWithWire})
