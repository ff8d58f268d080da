"""The patched runtimes' upstream: which upstream files they are, and our changes to them as a patch series.

``fmus/runtime/`` (pythonfmu, FMI 2.0) and ``fmus/runtime3/`` (pythonfmu3, FMI 3.0) are upstream's export runtimes
with nfal's fixes (``// nfal:``; docs/cosimulation.md, "Crash at exit"). Each folder holds:

* ``UPSTREAM.md``: the source, version and license, and how to move to a new upstream version;
* ``upstream.json``: the upstream repository, commit and folder, and the git blob id of every file taken;
* ``patches/``: nfal's changes, one patch per file, applied in name order (``git apply``).

:func:`check` proves that upstream plus the patches is the tree that is built: it copies the tree, takes the series
back out (``git apply -R``) and compares each file's git blob id with upstream's. :func:`refresh` writes the series
and the blob ids from an upstream checkout::

    python -m nfal.fmus.runtime_upstream refresh fmus/runtime ~/src/PythonFMU      # after editing the tree
    python -m nfal.fmus.runtime_upstream check fmus/runtime
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

RUNTIMES = ("runtime", "runtime3")
#: What a runtime folder holds besides upstream's files.
OWN_FILES = ("UPSTREAM.md", "upstream.json")


def blob_id(data: bytes) -> str:
    """The git blob id of ``data`` (``git hash-object``): what upstream's repository names the file by."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def tree_files(folder: Path) -> list[str]:
    """The upstream files of a runtime folder (relative, sorted): all but the series and its records."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                  if p.is_file() and p.relative_to(folder).parts[0] not in (*OWN_FILES, "patches"))


def record(folder: Path) -> dict:
    return json.loads((folder / "upstream.json").read_text(encoding="utf-8"))


def series(folder: Path) -> list[Path]:
    return sorted((folder / "patches").glob("*.patch"))


def upstream_of(folder: Path) -> dict[str, bytes]:
    """The tree with the patch series taken back out: {relative path: contents}."""
    with tempfile.TemporaryDirectory() as scratch:
        copy = Path(scratch) / "tree"
        shutil.copytree(folder, copy, ignore=shutil.ignore_patterns(*OWN_FILES, "patches"))
        for patch in reversed(series(folder)):
            done = subprocess.run(["git", "apply", "-R", str(patch.resolve())], cwd=copy,
                                  capture_output=True, text=True)
            if done.returncode != 0:
                raise ValueError(f"{patch.name} does not come back out of {folder}: {done.stderr.strip()}")
        return {name: (copy / name).read_bytes() for name in tree_files(copy)}


def check(folder: Path) -> list[str]:
    """What differs between upstream (``upstream.json``'s blob ids) and the tree less its series; [] when they agree."""
    expected = record(folder)["files"]
    found = {name: blob_id(data) for name, data in upstream_of(folder).items()}
    problems = [f"{name}: not in the tree" for name in sorted(set(expected) - set(found))]
    problems += [f"{name}: not upstream's (add it to upstream.json or remove it)"
                 for name in sorted(set(found) - set(expected))]
    problems += [f"{name}: blob {found[name][:12]}, upstream's {expected[name][:12]}: a change outside the series"
                 for name in sorted(set(found) & set(expected)) if found[name] != expected[name]]
    return problems


def refresh(folder: Path, checkout: Path) -> None:
    """Write ``patches/`` (one patch per changed file) and ``upstream.json``'s blob ids from an upstream checkout at
    the recorded commit (its ``path`` folder, and ``LICENSE`` from the repository's root)."""
    info = record(folder)
    base = checkout / info["path"]
    patches = folder / "patches"
    shutil.rmtree(patches, ignore_errors=True)
    patches.mkdir()
    files, written = {}, 0
    for name in tree_files(folder):
        original = (checkout if name == "LICENSE" else base) / name
        files[name] = blob_id(original.read_bytes())
        with tempfile.TemporaryDirectory() as scratch:  # a/NAME, b/NAME: the patch names the file as the tree does
            for side, source in (("a", original), ("b", folder / name)):
                (Path(scratch) / side / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source, Path(scratch) / side / name)
            diff = subprocess.run(["git", "diff", "--no-index", "--no-prefix", f"a/{name}", f"b/{name}"], cwd=scratch,
                                  capture_output=True)
        if diff.returncode == 1:  # the files differ
            header = f"nfal's changes to upstream's {name}: each hunk says why in its nfal: comment.\n\n"
            written += 1
            (patches / f"{written:04d}-{name.replace('/', '-')}.patch").write_bytes(header.encode() + diff.stdout)
        elif diff.returncode != 0:
            raise RuntimeError(diff.stderr.decode())
    info["files"] = files
    (folder / "upstream.json").write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=("check", "refresh"))
    parser.add_argument("folder", type=Path, help="fmus/runtime or fmus/runtime3")
    parser.add_argument("checkout", type=Path, nargs="?", help="refresh: upstream's repository at the recorded commit")
    args = parser.parse_args()
    if args.action == "refresh":
        if args.checkout is None:
            parser.error("refresh needs the upstream checkout")
        refresh(args.folder, args.checkout)
    problems = check(args.folder)
    for problem in problems:
        print(problem, file=sys.stderr)
    print(f"{args.folder}: upstream + {len(series(args.folder))} patches "
          f"{'is' if not problems else 'is NOT'} the tree")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
