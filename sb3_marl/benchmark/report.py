"""Aggregate a benchmark log folder into the paper's table and figures.

- ``paper_table.md``: per experiment, per curve and density, the final evaluation over seeds
  (the paper's: 30 seeded episodes of each trained model, :meth:`TrialLog.final`; mean ± std of
  the seeds' final evaluation returns; the interquartile mean of all the seeds' episode returns
  with a 95 % stratified-bootstrap confidence interval, :func:`iqm_with_ci`; collision rate, the
  return and collision rate of the policy alone (supervisor off, same episodes), lane changes and
  yields per episode, mean speed [m/s], acceleration std [m/s²] and supervisor intervention rate
  averaged over seeds) beside the paper's numbers and claims, each claim checked per density (returns
  by their IQM CIs, acceleration std by its range over seeds), and the hand-written reference
  policies (IDM/MOBIL, cruise, random) on the same episodes, with the learners against IDM/MOBIL;
- ``headline.md``: the README's and the docs' results tables (:func:`headline_table`): the
  paper's learners and ours with the supervisor beside the paper's Table 5, and alone;
- ``learning_curves_<experiment>.png``: evaluation return against training episodes, one panel
  per density, mean over seeds with a shaded ± std band (the layout of the paper's figures);
- ``final_returns.png``: the table's final returns at a glance: per experiment and density, each
  curve's IQM with its 95 % CI beside the paper's Table-5 numbers and IDM/MOBIL's;
- ``comfort.png``: AV acceleration traces of one evaluation episode with the comfort term on and
  off, and the acceleration std of the final evaluations;
- ``cooperative_lane_change.png`` / ``.json`` (the paper's experiment 6, policy interpretation):
  among the final evaluation episodes of the finished MA2C trials at densities 2 and 3, the
  lane change an AV yielded to with the largest speed drop (:mod:`sb3_marl.evaluation.interpretation`),
  as road snapshots and speed traces; the json says which, or that no AV yielded.

Only finished trials (with ``result.json``) enter the table; curves also show unfinished ones. A
trial with a damaged file, and one not evaluated yet, is left out, and the report says which and why.
The output folder is one the report creates, an empty one, or one an earlier report wrote (its
:data:`MANIFEST` lists the files it wrote); the files of an earlier report that this one does not
write again (a figure whose trials are gone) are deleted, so the folder shows one report. Nothing
else there is touched: a file the report did not write is never deleted.
"""

from __future__ import annotations

import json
from pathlib import Path

from sb3_marl.benchmark.figures import plot_comfort, plot_final_returns, plot_interpretation, plot_learning_curves
from sb3_marl.benchmark.runner import SETTINGS_FILE
from sb3_marl.benchmark.statistics import curve_summaries, load_trials, reference_summaries
from sb3_marl.benchmark.tables import headline_table, paper_table
from sb3_marl.benchmark.traffic_view import write_traffic
from sb3_marl.common.files import inside, read_json_object, write_text

#: The report's manifest in its output folder: the names of the files it wrote there last time,
#: the only files a later report deletes.
MANIFEST = ".sb3-marl-report.json"


def write_report(log_folder: str | Path, out_dir: str | Path = "results", seed: int = 10_000) -> list[Path]:
    """Write ``paper_table.md``, the learning curves and the comfort figure of ``log_folder`` into
    ``out_dir``; returns the files written.

    :raises FileNotFoundError: if ``log_folder`` has no evaluated trial
    """
    problems: list[str] = []
    trials = load_trials(log_folder, problems)
    for problem in problems:  # each trial left out and why (a damaged file: the next run of the grid repairs it)
        print(f"left out of the report: {problem}")
    if not trials:
        raise FileNotFoundError(
            f"No evaluated benchmark trial under {Path(log_folder) / 'trials'}/ "
            "(run `sb3-marl benchmark` with this --log-folder first)."
        )
    out_dir = Path(out_dir)
    earlier = _earlier_outputs(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    settings_path = Path(log_folder) / SETTINGS_FILE
    settings = read_json_object(settings_path) if settings_path.is_file() else None
    table = out_dir / "paper_table.md"
    references = reference_summaries(trials, log_folder, seed)
    summaries = curve_summaries(trials)
    write_text(table, paper_table(trials, settings, references, summaries))
    headline = out_dir / "headline.md"
    write_text(headline, headline_table(summaries, references))
    written = [table, headline, *plot_learning_curves(trials, out_dir)]
    for figure in (plot_final_returns(summaries, out_dir, references), plot_comfort(trials, log_folder, out_dir, seed)):
        if figure is not None:
            written.append(figure)
    written += plot_interpretation(trials, log_folder, out_dir, seed)
    written += write_traffic(trials, log_folder, out_dir, seed, references)
    for name in sorted(earlier - {path.name for path in written}):
        inside(out_dir / name, out_dir).unlink(missing_ok=True)  # an earlier report's, not written now
    write_text(out_dir / MANIFEST, json.dumps(sorted(path.name for path in written), indent=1) + "\n")
    return written


def _earlier_outputs(out_dir: Path) -> set[str]:
    """The names of the files an earlier report wrote into ``out_dir`` (its manifest); a ValueError
    naming ``-o`` if ``out_dir`` is a file, or a folder with files but no manifest (another's)."""
    manifest = out_dir / MANIFEST
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"-o/--output {out_dir} is a file, not a folder.")
    if not manifest.is_file():
        if out_dir.is_dir() and any(out_dir.iterdir()):
            raise ValueError(
                f"-o/--output {out_dir} holds files that no report wrote (no {MANIFEST}); "
                "give a new or empty folder, or the folder of an earlier report."
            )
        return set()
    try:
        names = json.loads(inside(manifest, out_dir).read_text())
    except (OSError, ValueError, UnicodeDecodeError) as error:
        raise ValueError(f"{manifest}: not the list of files a report wrote ({error}).") from None
    if not isinstance(names, list) or not all(isinstance(n, str) and n == Path(n).name for n in names):
        raise ValueError(f"{manifest}: expected a list of file names in {out_dir}, got {str(names)[:200]}.")
    return set(names)


__all__ = ["MANIFEST", "write_report"]
