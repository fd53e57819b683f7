"""What a study leaves on disk, and reading it back.

Layout of an output folder: one folder per scenario, holding ``scenario.json`` and one Parquet
file per finished trial (``trial-0003.parquet``, the scenario and seed in its metadata). A trial
file is written to a temporary name and renamed, so it is either whole or absent: that is what
makes a sweep resumable. ``<scenario>.csv`` and ``<scenario>.parquet`` beside the folder hold
every trial's rows together, with a ``trial`` column.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from ktbt_proto.files import replacing, write_atomic
from ktbt_sim.records import read_release_csv, release_name, release_scenario, write_release_csv
from ktbt_sim.scenario import Scenario


@dataclass(frozen=True)
class Results:
    """Every finished trial of one scenario, aligned on the recorded iterations."""

    scenario: Scenario
    trials: tuple[int, ...]
    iterations: np.ndarray
    """(rows,): the iteration of each recorded step."""
    data: dict[str, np.ndarray]
    """column -> (trials, rows)."""

    def __getitem__(self, column: str) -> np.ndarray:
        return self.data[column]

    @property
    def total_targets(self) -> int:
        return self.scenario.targets.total


def trial_path(folder: Path, trial: int) -> Path:
    return folder / f"trial-{trial:04d}.parquet"


def write_trial(
    folder: Path, scenario: Scenario, trial: int, seed: int, rows: dict[str, list[int]]
) -> Path:
    """Write one trial durably (``ktbt_proto.files.replacing``): whole or absent."""
    folder.mkdir(parents=True, exist_ok=True)
    table = pa.table({name: pa.array(values, pa.int64()) for name, values in rows.items()})
    meta = {b"ktbt.scenario": scenario.dump().encode(), b"ktbt.trial": str(trial).encode()}
    meta[b"ktbt.seed"] = str(seed).encode()
    table = table.replace_schema_metadata(meta)
    final = trial_path(folder, trial)
    with replacing(final) as tmp:
        pq.write_table(table, tmp)
    return final


def read_trial(path: Path) -> dict[str, list[int]]:
    table = pq.read_table(path)
    return {name: table.column(name).to_pylist() for name in table.column_names}


def finished(folder: Path) -> set[int]:
    """Trials whose file is complete (a torn temporary file does not count)."""
    done = set()
    for path in folder.glob("trial-*.parquet"):
        try:
            done.add(int(path.stem.split("-")[1]))
        except ValueError:
            continue
    return done


def load_folder(folder: Path) -> Results | None:
    scenario_file = folder / "scenario.json"
    if not scenario_file.exists():
        return None
    try:
        scenario = Scenario.model_validate(json.loads(scenario_file.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{scenario_file}: not a scenario ({exc})") from None
    trials = sorted(finished(folder))
    if not trials:
        return None
    tables = []
    for t in trials:
        try:
            tables.append(pq.read_table(trial_path(folder, t)))
        except (OSError, ValueError) as exc:
            raise ValueError(f"{trial_path(folder, t)}: unreadable ({exc}); remove it") from None
    rows = min(t.num_rows for t in tables)
    names = [n for n in tables[0].column_names if n != "iteration"]
    data = {name: np.stack([t.column(name).to_numpy()[:rows] for t in tables]) for name in names}
    iterations = tables[0].column("iteration").to_numpy()[:rows]
    return Results(scenario, tuple(trials), iterations, data)


def load(directory: str | Path) -> dict[str, Results]:
    """Every scenario with at least one finished trial under ``directory``, by name: our
    scenario folders, and the release's ``SimData`` scenario folders (``…_Tr_N.csv``), which
    are named ``release <folder>``. ``directory`` may itself be a release scenario folder."""
    root = Path(directory)
    out: dict[str, Results] = {}
    for folder in [root, *sorted(p for p in root.iterdir() if p.is_dir())]:
        results = load_folder(folder)
        if results is None and any(folder.glob("*_Tr_*.csv")):
            results = read_release_folder(folder)
        if results is not None:
            out[results.scenario.name] = results
    return out


def combine(folder: Path) -> None:
    """Write ``<scenario>.parquet`` and ``<scenario>.csv`` with every finished trial's rows."""
    trials = sorted(finished(folder))
    if not trials:
        return
    tables = []
    for t in trials:
        table = pq.read_table(trial_path(folder, t))
        tables.append(table.add_column(0, "trial", pa.array([t] * table.num_rows, pa.int64())))
    combined = pa.concat_tables(tables).replace_schema_metadata(
        {b"ktbt.scenario": (folder / "scenario.json").read_bytes()}
    )
    for suffix in (".parquet", ".csv"):
        with replacing(folder.with_suffix(suffix)) as tmp:
            if suffix == ".csv":
                pacsv.write_csv(combined, tmp)
            else:
                pq.write_table(combined, tmp)


def read_release_folder(folder: str | Path) -> Results:
    """A release ``SimData`` scenario folder (one ``…_Tr_N.csv`` per trial) as our results,
    aligned on the iterations every trial has."""
    folder = Path(folder)
    files = sorted(folder.glob("*_Tr_*.csv"), key=lambda p: int(p.stem.rsplit("_", 1)[1]))
    if not files:
        raise ValueError(f"{folder}: no release trial CSVs (*_Tr_N.csv)")
    trials = [read_release_csv(p) for p in files]
    common = set(trials[0]["iteration"].tolist())
    for t in trials[1:]:
        common &= set(t["iteration"].tolist())
    iterations = np.array(sorted(common), dtype=np.int64)
    if not len(iterations):
        raise ValueError(f"{folder}: the trials share no recorded iteration")
    data: dict[str, np.ndarray] = {}
    for name in trials[0]:
        if name == "iteration":
            continue
        stacked = []
        for t in trials:
            index = np.searchsorted(t["iteration"], iterations)
            stacked.append(t[name][index])
        data[name] = np.stack(stacked)
    numbers = tuple(int(p.stem.rsplit("_", 1)[1]) for p in files)
    scenario = release_scenario(folder, int(iterations[-1]))
    return Results(scenario, numbers, iterations, data)


def export_release(folder: Path) -> Path:
    """Every finished trial of a ``ktbt sim run`` scenario folder in the release's format: a
    release ``SimData`` scenario folder ``<folder>/release/<release name>/`` holding
    ``<release name>_Tr_<trial + 1>.csv`` (the release numbers trials from 1)."""
    scenario = Scenario.model_validate(json.loads((folder / "scenario.json").read_text("utf-8")))
    name = release_name(scenario)
    target = folder / "release" / name
    target.mkdir(parents=True, exist_ok=True)
    write_atomic(
        target / "README.txt",
        "One CSV per trial in the release's format (a row every 10 iterations, 35 columns).\n"
        "As in the release's own files, the three columns headed 'Known St. RG', 'Known St.\n"
        "RY' and 'Known St. RB' hold the robots knowing red and yellow, red and blue, and red\n"
        "and green, in that order: the release writes them in that order under that header.\n",
    )
    for trial in sorted(finished(folder)):
        rows = read_trial(trial_path(folder, trial))
        write_release_csv(target / f"{name}_Tr_{trial + 1}.csv", rows)
    return target
