"""Provenance: what a run or a campaign was made of, and by which cellsim.

A run is a pure function of its *inputs*: the scenario file and its bases,
every file the loaded scenario uses (the validation file it names, each
safety controller's risk model, each robot's model and the files that model
names, such as meshes), the ``--set`` overrides, the seed, the duration and
cellsim's version. :func:`read_inputs` reads those files once; :meth:`Inputs.identity`
is their *content identity*: a SHA-256 over the files' bytes (not their paths,
so it is the same on every machine) and the other inputs, with a digest per
file so that :func:`changes` says what differs between two identities
("risk model scenarios/welding_cell_risk_model.yaml changed").

Two uses:

* A campaign is identified by the identity of its inputs and runs from a
  snapshot of them (:func:`snapshot_scenario`, ``OUT/inputs/``), so a file
  edited while it runs, or before it is resumed, never leaks into it.
* A run folder holds copies of the files the run used (``inputs/<module>/``),
  which its ``scenario.yaml`` (written whole: no base, validation inline)
  refers to (:func:`write_run_scenario`): re-running
  it a year later, from wherever the folder was moved, gives the same black box.

:func:`provenance` is the record kept in every black box (metadata key
``provenance``) and in a campaign's ``results.json``: versions, command line,
working directory, time, and the content identity of the inputs.

Not followed: ``package://`` and other URIs in a robot model (resolved by
Drake's package map, not by cellsim), and files a robot model names by an
absolute path are hashed but neither copied nor snapshotted.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import shlex
import sys
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from cellsim.version import __version__
from cellsim.atomic import write_text
from cellsim.config.typed_yaml import ConfigError, dump_yaml, from_data, to_data

IDENTITY_FORMAT = 2
"""Version of the identity record; identities of different formats never match."""
BLACKBOX = "blackbox.sqlite"
"""A run folder's black box."""
RESOLVED_SCENARIO = "scenario.yaml"
"""A run folder's resolved scenario (it re-runs the run)."""
PLAN = "campaign.json"
"""A campaign's (or a search's) folder: its plan, what makes the folder one."""
REPORT = "report.html"
"""A campaign's (or a search's) folder: its report."""


def simulator_versions() -> dict[str, str]:
    """The versions a simulated run's numbers depend on (cellsim, Drake, NumPy): runs of one campaign must share
    them (its identity holds them; a cluster's workers are checked against them)."""
    versions = package_versions()
    return {k: versions[k] for k in ("cellsim", "drake", "numpy")}


def package_versions() -> dict[str, str]:
    """The versions of Python and of the packages a run's result depends on."""
    import importlib.metadata

    versions = {"python": platform.python_version()}
    for package in ("cellsim", "drake", "numpy", "pyyaml", "rich"):
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


INPUTS = "inputs"
"""The folder, in a run folder or a campaign folder, holding copies of the inputs."""
MODEL_SUFFIXES = (".urdf", ".sdf", ".xml")
"""Robot models read as XML for the files they name (``<mesh filename=...>``, ``<uri>``)."""


class SnapshotError(Exception):
    """The inputs could not be snapshotted so that they load back the same."""


@dataclass(frozen=True)
class InputFile:
    """One input file, read once: a snapshot or a copy is made of these very bytes."""

    key: str
    """Stable name: ``scenario``, ``validation.file``, the scenario key naming the file
    (``behaviours.safety_controller.risk_model``) or, for a file named by another,
    ``<that file's key>:<the reference as written>``."""
    role: str
    """What a message calls it: ``risk model``, ``validation file``, ..."""
    path: Path
    """Where it was read (absolute)."""
    data: bytes = field(repr=False, compare=False)
    sha256: str = ""
    module: str | None = None
    """The module whose field names the file (files named in the scenario)."""
    parent: str | None = None
    """The key of the file naming this one (a mesh of a URDF)."""
    ref: str | None = None
    """The reference as written in the parent."""

    in_memory: bool = False
    """Not read from ``path``: a scenario built in Python, its text made here (nothing on disk to re-read)."""

    @classmethod
    def read(cls, key: str, role: str, path: Path, **kwargs) -> "InputFile":
        data = Path(path).read_bytes()
        return cls(key, role, Path(path), data, hashlib.sha256(data).hexdigest(), **kwargs)

    @classmethod
    def of_text(cls, key: str, role: str, path: Path, text: str) -> "InputFile":
        """An input that is no file: ``text`` stands for it, as if read from ``path``."""
        data = text.encode("utf-8")
        return cls(key, role, Path(path), data, hashlib.sha256(data).hexdigest(), in_memory=True)

    @property
    def named_absolutely(self) -> bool:
        """Named by an absolute path in its parent: cannot be relocated with it."""
        return self.ref is not None and (self.ref.startswith("file://") or os.path.isabs(self.ref))


@dataclass
class Inputs:
    """The input files of a loaded scenario, the scenario file first."""

    files: list[InputFile]

    def identity(self, overrides, seed: int | None, duration: float | None) -> dict:
        """The content identity of these files with the other inputs of a run or campaign.

        ``hash`` covers the files' digests (by key, not path), the overrides, seed,
        duration and the versions of cellsim, Drake and NumPy (:func:`simulator_versions`): a campaign resumed
        after an upgrade would mix runs of two simulators; ``files`` also names where each was read.
        """
        essence = {
            "format": IDENTITY_FORMAT,
            "cellsim": __version__,
            "simulator": simulator_versions(),
            "overrides": list(overrides),
            "seed": seed,
            "duration": duration,
            "files": {f.key: f.sha256 for f in self.files},
        }
        digest = hashlib.sha256(json.dumps(essence, sort_keys=True).encode()).hexdigest()
        return {
            "hash": digest,
            **{k: v for k, v in essence.items() if k != "files"},
            "files": {f.key: {"role": f.role, "path": str(f.path), "sha256": f.sha256} for f in self.files},
        }

    def digests(self) -> dict[str, str]:
        return {f.key: f.sha256 for f in self.files}

    def check_unchanged(self) -> None:
        """ConfigError if a file no longer holds the bytes read (edited meanwhile)."""
        for f in self.files:
            if f.in_memory:
                continue
            try:
                same = f.path.read_bytes() == f.data
            except OSError:
                same = False
            if not same:
                raise ConfigError(str(f.path), None, "", f"the {f.role} changed while the run was being prepared; run again")

    def write_snapshot(self, dest: Path) -> tuple[Path, dict[str, str]]:
        """Write every file under ``dest``, keeping their layout relative to one another; returns the
        scenario's copy, and the digests of the copies whose text had to change: a scenario (or base)
        naming its base by an absolute path names the base's copy instead, by a relative one."""
        root = Path(os.path.commonpath([f.path.parent for f in self.files]))
        copies = {f.key: dest / f.path.relative_to(root) for f in self.files}
        changed = {}
        for f in self.files:
            data = f.data
            base = copies.get("base 1" if f.key == "scenario" else f"base {int(f.key[5:]) + 1}"
                              if f.key.startswith("base ") else "")
            if base is not None:
                data = _rebase(data, os.path.relpath(base, copies[f.key].parent), f.path)
                if data != f.data:
                    changed[f.key] = hashlib.sha256(data).hexdigest()
            copies[f.key].parent.mkdir(parents=True, exist_ok=True)
            copies[f.key].write_bytes(data)
        return copies["scenario"], changed


def _rebase(data: bytes, relative: str, source: Path) -> bytes:
    """A scenario's text with its top-level ``base:`` naming ``relative`` instead of an absolute path
    (unchanged when it names a relative one, which the snapshot's layout keeps)."""
    import re

    from cellsim.config.typed_yaml import parse_yaml

    def base_of(text: str):  # read as every scenario is (its !replace tags known), not by a loader that refuses them
        try:
            return parse_yaml(text, str(source)).get("base")
        except (ConfigError, AttributeError):
            return None

    text = data.decode("utf-8")
    named = base_of(text)
    if not isinstance(named, str) or not os.path.isabs(named):
        return data
    rebased = re.sub(r"(?m)^base:.*$", lambda _: f"base: {json.dumps(relative)}", text, count=1)
    if base_of(rebased) != relative:
        raise SnapshotError(f"{source}: cannot point its base: at the snapshot's copy")
    return rebased.encode("utf-8")


def read_inputs(sf) -> Inputs:
    """The files the loaded scenario ``sf`` uses, read now (OSError if one cannot be)."""
    from cellsim.registry import kind_of

    if getattr(sf, "built_in_code", False):  # no file: the scenario's own text, as a file of it would read
        from cellsim.config.typed_yaml import dump_yaml, to_data

        files = [InputFile.of_text("scenario", "scenario built in Python", Path(sf.source), dump_yaml(to_data(sf.scenario)))]
    else:
        files = [InputFile.read("scenario", "scenario", Path(sf.source).resolve())]
    # the scenario's bases (``base: other.yaml``), nearest first
    for i, base in enumerate((getattr(sf.loaded, "files", None) or [sf.source])[1:], start=1):
        files.append(InputFile.read(f"base {i}", "scenario base", Path(base).resolve()))
    if sf.validation_file is not None:
        files.append(InputFile.read("validation.file", "validation file", Path(sf.validation_file.source).resolve()))
    sc = sf.scenario
    for section in ("entities", "behaviours", "services"):
        for module, cfg in getattr(sc, section).items():
            for name, role in kind_of(cfg).files.items():
                if getattr(cfg, name) is None:
                    continue  # an optional file not given
                key = f"{section}.{module}.{name}"
                top = InputFile.read(key, role, sf.resolve_path(key, getattr(cfg, name)), module=module)
                files.append(top)
                files.extend(_named_files(top))
    return Inputs(files)


def _named_files(f: InputFile) -> list[InputFile]:
    """The existing local files an XML robot model names (meshes and the like)."""
    if f.path.suffix.lower() not in MODEL_SUFFIXES:
        return []
    try:
        tree = ElementTree.fromstring(f.data)
    except ElementTree.ParseError:
        return []  # not ours to judge: Drake reports a malformed model
    found: dict[str, InputFile] = {}
    for element in tree.iter():
        refs = [element.attrib.get("filename")]
        if isinstance(element.tag, str) and element.tag.rpartition("}")[2] == "uri":
            refs.append(element.text)
        for ref in refs:
            ref = (ref or "").strip()
            if not ref or ref in found:
                continue
            local = ref.removeprefix("file://")
            if "://" in local:
                continue  # package:// and the like: Drake's package map, not a path
            path = Path(os.path.normpath(f.path.parent / local))
            if path.is_file():
                found[ref] = InputFile.read(f"{f.key}:{ref}", f"file of the {f.role}", path, parent=f.key, ref=ref)
    return list(found.values())


# --------------------------------------------------------------------------- identities


def changes(old: dict, new: dict) -> list[str]:
    """What differs between two content identities, in words (empty if nothing)."""
    found = []
    if old.get("format") != new.get("format"):
        found.append(f"inputs recorded in format {old.get('format')}, this cellsim writes {new.get('format')}")
    if old.get("cellsim") != new.get("cellsim"):
        found.append(f"cellsim version {old.get('cellsim')} -> {new.get('cellsim')}")
    old_sim, new_sim = old.get("simulator") or {}, new.get("simulator") or {}
    found += [f"{k} version {old_sim.get(k)} -> {new_sim.get(k)}" for k in ("drake", "numpy")
              if old_sim.get(k) != new_sim.get(k) and old.get("format") == new.get("format")]
    old_files, new_files = old.get("files", {}), new.get("files", {})
    for key in [*old_files, *(k for k in new_files if k not in old_files)]:
        a, b = old_files.get(key), new_files.get(key)
        if a is None:
            found.append(f"{b['role']} {show_path(b['path'])} added")
        elif b is None:
            found.append(f"{a['role']} {show_path(a['path'])} no longer used")
        elif a["sha256"] != b["sha256"]:
            if Path(a["path"]).name == Path(b["path"]).name:  # the same file, perhaps moved with the campaign
                found.append(f"{b['role']} {show_path(b['path'])} changed")
            else:
                found.append(f"{b['role']} {show_path(a['path'])} -> {show_path(b['path'])} (other content)")
    if old.get("overrides") != new.get("overrides"):
        found.append(f"overrides differ ({_sets(old.get('overrides'))} -> {_sets(new.get('overrides'))})")
    if old.get("seed") != new.get("seed"):
        found.append(f"seed {old.get('seed')} -> {new.get('seed')}")
    if old.get("duration") != new.get("duration"):
        found.append(f"duration {_duration(old.get('duration'))} -> {_duration(new.get('duration'))}")
    if not found and old.get("hash") != new.get("hash"):
        found.append("inputs differ")
    return found


def show_path(path: str | os.PathLike) -> str:
    """A path relative to the working directory when it is below it."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def _sets(overrides) -> str:
    return " ".join(f"--set {shlex.quote(o)}" for o in overrides) if overrides else "none"


def _duration(value) -> str:
    return "the scenario's" if value is None else f"{value:g} s"


# --------------------------------------------------------------------------- snapshots and run folders


def snapshot_scenario(inputs: Inputs, dest: Path, overrides) -> tuple[Path, tuple[str, ...]]:
    """Snapshot ``inputs`` into ``dest``; returns the scenario to load from it and the
    overrides to add to ``overrides`` so that it uses the snapshot's files.

    Files named by relative paths keep their layout and need none; one named by an
    absolute path (or through a symbolic link the layout does not follow) is pinned
    to its copy by an override. The snapshot must load back to the very inputs
    read, or SnapshotError.
    """
    scenario, rebased = inputs.write_snapshot(dest)
    # the files a configuration point names (a base is named by its scenario's text, rebased above)
    top = [f for f in inputs.files if f.parent is None and f.key != "scenario" and not f.key.startswith("base ")]
    root = Path(os.path.commonpath([f.path.parent for f in inputs.files]))
    all_pinned = tuple(f"{f.key}={json.dumps(str(dest / f.path.relative_to(root)))}" for f in top)
    problem = "the copies load back to other files"
    for pins in ((), all_pinned):
        from cellsim.scenario import load_scenario

        try:
            again = read_inputs(load_scenario(scenario, [*overrides, *pins]))
        except (ConfigError, OSError) as e:
            problem = str(e)
            continue
        inside = all(f.path.resolve().is_relative_to(dest.resolve()) for f in again.files if not f.named_absolutely)
        if inside and again.digests() == {**inputs.digests(), **rebased}:
            return scenario, pins
    raise SnapshotError(f"cannot snapshot the inputs into {dest}: {problem}")


def write_run_scenario(
    sf, inputs: Inputs, out_dir: Path, name: str = "scenario.yaml", seed: int | None = None, duration: float | None = None,
    extended_by: str | None = None,
) -> None:
    """Write ``out_dir/name``, the resolved scenario with the run's ``seed`` and
    ``duration``, and copies of the files it uses; ``extended_by``: the script's function that added systems of
    its own to the diagram (said in the file's header: the scenario alone does not re-run such a run).

    The copies are ``inputs/<module>/<file>`` (a robot model with the files it
    names, in their layout) and the scenario refers to them, so the folder
    re-runs alone, wherever it is. The validation section is written inline.
    The scenario is written first: a folder holding it is a run's (see
    ``cellsim.simulation.RunFolder``).
    """
    from cellsim.scenario import Scenario

    copy = from_data(Scenario, to_data(sf.scenario))
    copy.seed = copy.seed if seed is None else seed
    copy.duration = copy.duration if duration is None else duration
    placed: dict[str, Path] = {}
    folders: set[Path] = set()
    for f in inputs.files:
        if f.module is None:
            continue  # the scenario, written resolved; the validation file, inline
        named = [d for d in inputs.files if d.parent == f.key and not d.named_absolutely]
        root = Path(os.path.commonpath([f.path.parent, *(d.path.parent for d in named)]))
        section, module, field_name = f.key.split(".")
        folder = Path(INPUTS) / module
        if folder in folders:
            folder = Path(INPUTS) / f"{module}-{field_name}"
        folders.add(folder)
        placed[f.key] = folder / f.path.relative_to(root)
        placed.update({d.key: folder / d.path.relative_to(root) for d in named})
        setattr(getattr(copy, section)[module], field_name, placed[f.key].as_posix())
    header = f"Resolved scenario exported by cellsim from {sf.source}"
    if sf.overrides:
        header += "\nwith overrides: " + " ".join(sf.overrides)
    if placed:
        header += f"\nThe files it uses are copies, in {INPUTS}/, of those the run used."
    if extended_by:
        header += (f"\nThe run's diagram was extended by {extended_by} (systems of a script's own): this scenario "
                   "alone builds the cell without them and does not re-run the run.")
    write_text(out_dir / name, dump_yaml(copy, header=header))
    data = {f.key: f.data for f in inputs.files}
    for key, relative in placed.items():
        target = out_dir / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data[key])


# --------------------------------------------------------------------------- the record


def command_line() -> str:
    """This process's command line, shell-quoted."""
    return shlex.join(sys.argv)


def provenance(identity: dict | None = None, **extra) -> dict:
    """What produced a result: versions, command line, working directory, time, inputs."""

    record = {
        "versions": package_versions(),
        "command": command_line(),
        "executable": sys.executable,
        "cwd": os.getcwd(),
        "platform": platform.platform(),
        "created": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "inputs": identity,
    }
    record.update(extra)
    return record
