"""Run the corpus of broken inputs (tests/test_broken_inputs.py) through the command line of a given
freqbrdf source tree, in fresh processes, and record each case's outcome: exit code, lines on stderr,
a traceback or not, files written or removed. A case is handled when it gives one line on stderr,
the expected exit code, and writes and removes nothing.

    python benchmarks/studies/broken_inputs.py [--source PATH/src] [--name broken_inputs]

Writes benchmarks/results/<name>.json and <name>.md (one row per case). ``--source`` runs another
source tree (e.g. a ``git worktree`` of another version) under another ``--name``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"


def _corpus():
    spec = importlib.util.spec_from_file_location("corpus", ROOT / "tests" / "test_broken_inputs.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["corpus"] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _fit_folder(capture: Path, folder: Path) -> Path:
    from freqbrdf import pipeline
    from freqbrdf.capture.layouts import load
    from freqbrdf.config import Config, TexelConfig

    config = Config(texels=TexelConfig(texture_res=16))
    return pipeline.write_fit(folder, pipeline.fit(load(capture), config), config)


def run_case(corpus, case, good: Path, fitted: Path, source: Path, scratch: Path) -> dict:
    """One case in a fresh folder and a fresh process of ``source``'s command line."""
    work = scratch / "case"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir()
    arguments, _ = corpus.prepare_case(case, good, fitted, work)
    before = corpus._snapshot(work)
    env = {**os.environ, "PYTHONPATH": str(source), "FREQBRDF_RERUN": "1"}
    try:
        done = subprocess.run([sys.executable, "-m", "freqbrdf.cli", *arguments], cwd=work, env=env,
                              capture_output=True, text=True, timeout=600)
        code, err, out = done.returncode, done.stderr, done.stdout
    except subprocess.TimeoutExpired:
        code, err, out = None, "timed out after 600 s", ""
    after = corpus._snapshot(work)
    lines = [line for line in err.strip().splitlines() if line.strip()]
    written = sorted(name for name in after if name not in before or after[name] != before[name])
    removed = sorted(name for name in before if name not in after)
    outcome = {
        "case": case.name, "exit_code": code, "expected_exit_code": case.code, "stderr_lines": len(lines),
        "traceback": "Traceback" in err + out, "written": len(written), "removed": len(removed),
        "first_line": (lines[0] if lines else "")[:160], "last_line": (lines[-1] if lines else "")[:160],
    }
    outcome["ok"] = (code == case.code and len(lines) == 1 and not outcome["traceback"] and not written
                     and not removed)
    return outcome


def _table(result: dict) -> str:
    rows = ["| case | exit, lines | handled | the line |", "|---|---|---|---|"]
    for row in result["cases"]:
        line = row["last_line"].replace("|", "\\|")
        extra = (f"{', traceback' if row['traceback'] else ''}{', wrote ' + str(row['written']) if row['written'] else ''}"
                 f"{', removed ' + str(row['removed']) if row['removed'] else ''}")
        rows.append(f"| {row['case']} | {row['exit_code']}, {row['stderr_lines']}{extra} | "
                    f"{'✓' if row['ok'] else '✗'} | {line} |")
    header = (f"Broken inputs through the command line: {result['ok']} of {len(result['cases'])} cases handled "
              f"(one line, the right exit code, nothing written or removed).\n\n")
    return header + "\n".join(rows) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--source", type=Path, default=ROOT / "src", help="the src/ folder of the freqbrdf to run")
    parser.add_argument("--name", default="broken_inputs")
    arguments = parser.parse_args()
    source = arguments.source.resolve()
    commit = subprocess.run(["git", "-C", str(source), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    corpus = _corpus()
    from freqbrdf.synthetic.synth import synthesize

    with tempfile.TemporaryDirectory() as scratch_name:
        scratch = Path(scratch_name)
        good = synthesize(scratch / "good", corpus.TINY, progress=False)
        fitted = _fit_folder(good, scratch / "fit")
        cases = []
        for case in corpus.CASES:
            outcome = run_case(corpus, case, good, fitted, source, scratch)
            print(f"{'ok ' if outcome['ok'] else 'BAD'} {case.name}: exit {outcome['exit_code']}, "
                  f"{outcome['stderr_lines']} lines{', traceback' if outcome['traceback'] else ''}", flush=True)
            cases.append(outcome)
    document = {"source_commit": commit, "cases": cases, "ok": sum(row["ok"] for row in cases)}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{arguments.name}.json").write_text(json.dumps(document, indent=2) + "\n")
    print(f"{document['ok']} of {len(cases)} cases ok at {commit}")
    (RESULTS / f"{arguments.name}.md").write_text(_table(document))


if __name__ == "__main__":
    main()
