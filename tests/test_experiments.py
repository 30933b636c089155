"""Every experiment file of ``experiments/`` loads and validates, and the paper's tables are laid
out as the paper's (tab:result_protocol, tab:metrics_per_challenges, tab:ablation_study,
tab:embedded_results)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mata_eval.run.config import find_experiment, load_experiment, shipped_experiments
from mata_eval.report.paper import ablation_marks, embedded_role, is_mata, protocol_label
from mata_eval.run.timing_profile import read_profile

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = sorted((ROOT / "experiments").glob("*.yaml"))


@pytest.fixture(autouse=True)
def _repo_cwd(monkeypatch):
    monkeypatch.chdir(ROOT)  # timing-profile paths in the files are relative to the repository root


def key(spec):
    """Where a run sits in Table 1: (dataset, occlusion on, protocol, tracker, MATA)."""
    r = spec.resolved
    return (r["dataset"]["name"], r["occlusion"] is not None, protocol_label(r["protocol"])[0],
            r["tracker"]["name"], is_mata(r))


def test_every_experiment_file_is_here():
    names = {p.name for p in EXPERIMENTS}
    assert {"quickstart.yaml", "protocols.yaml", "challenges.yaml", "ablation.yaml", "embedded.yaml"} <= names
    assert {"protocols_real.yaml", "challenges_real.yaml", "ablation_real.yaml", "embedded_real.yaml"} <= names


@pytest.mark.parametrize("path", EXPERIMENTS, ids=[p.name for p in EXPERIMENTS])
def test_experiment_loads_and_validates(path):
    exp = load_experiment(path)
    assert exp.runs
    assert len({r.name for r in exp.runs}) == len(exp.runs)
    shared = all(str(r.resolved["dataset"].get("root", "")).startswith("../shared/data/") for r in exp.runs)
    if not path.stem.endswith("_real") and not shared:  # the default runs use the built-in synthetic
        assert {r.dataset.name for r in exp.runs} == {"synthetic"}  # suite (live*.yaml: ../shared/data)


def test_protocols_is_table_1():
    exp = load_experiment(ROOT / "experiments/protocols.yaml")
    keys = {key(r) for r in exp.runs}
    assert len(keys) == len(exp.runs) == 2 * 2 * 2 * 3  # no two runs in one cell
    assert {k[2] for k in keys} == {"LTP", "EOP @ 30 Hz", "EOP @ 10 Hz"}
    assert {k[1] for k in keys} == {False, True}  # clean and occlusion-augmented column groups
    for r in exp.runs:
        proto = r.resolved["protocol"]
        if proto["name"] == "eop":  # the paper's EOP: one-period tracker latency, other blocks at 30 Hz, no delay
            assert proto["tracker_latency"] == "period" and proto["egomotion_hz"] is None
            assert proto["estimator_latency"] == "none"
        assert (r.egomotion is None) == (r.estimator is None) == (not is_mata(r.resolved))


def test_protocols_real_has_the_papers_three_column_groups():
    exp = load_experiment(ROOT / "experiments/protocols_real.yaml")
    groups = {(k[0], k[1]) for k in map(key, exp.runs)}
    assert groups == {("uav123", False), ("uav123", True), ("vtuav", False)}  # UAV123, UAV123+occ, VTUAV
    assert len({key(r) for r in exp.runs}) == len(exp.runs)


@pytest.mark.parametrize("pair", [("challenges", "protocols"), ("challenges_real", "protocols_real")])
def test_challenges_runs_are_the_eop10_occlusion_runs_of_protocols(pair):
    ch = load_experiment(ROOT / f"experiments/{pair[0]}.yaml")
    pr = load_experiment(ROOT / f"experiments/{pair[1]}.yaml")
    assert ch.output == pr.output
    by_name = {r.name: r for r in pr.runs}
    for r in ch.runs:  # same folder, same name, same configuration: a run is computed once
        assert r.name in by_name and by_name[r.name].config_hash == r.config_hash
        assert r.occlusion is not None and protocol_label(r.resolved["protocol"])[0] == "EOP @ 10 Hz"
    assert {(r.tracker.name, is_mata(r.resolved)) for r in ch.runs} == {
        (t, m) for t in {r.tracker.name for r in pr.runs} for m in (False, True)}


# paper tab:ablation_study: (ego motion, EKF) marks of configurations 1 to 7
PAPER_ABLATION = {"1": (False, False), "2": (True, True), "3": (False, False), "4": (False, True),
                  "5": (True, True), "6": (True, True), "7": (True, True)}


@pytest.mark.parametrize("name", ["ablation", "ablation_real"])
def test_ablation_is_table_3(name):
    """The paper's seven configurations; the synthetic one runs them on block C's default preset
    (``mata``) with the paper's filter as an eighth row, the real one on the paper's preset."""
    exp = load_experiment(ROOT / f"experiments/{name}.yaml")
    runs = {r.name.split("-")[0]: r for r in exp.runs}
    extra = {"8": (True, True)} if name == "ablation" else {}
    assert sorted(runs) == sorted({**PAPER_ABLATION, **extra})
    details = {}
    for n, r in runs.items():
        ego, ekf, _, details[n] = ablation_marks(r.resolved)
        assert (ego, ekf) == {**PAPER_ABLATION, **extra}[n], n
        assert r.occlusion is not None and protocol_label(r.resolved["protocol"])[0] == "EOP @ 10 Hz"
    prefix = "improved block C (preset mata), " if name == "ablation" else ""
    assert details["4"] == prefix + "no camera compensation"
    assert details["5"] == prefix + "constant acceleration model"
    assert details["6"] == prefix + "constant jerk model" and details["7"] == prefix + "no threshold on measurements"
    paper = "MATA, the paper's block C (preset paper)"
    assert details["2"] == ("improved block C (preset mata)" if name == "ablation" else paper)
    if extra:
        assert details["8"] == paper and runs["8"].resolved["estimator"]["preset"] == "paper"


@pytest.mark.parametrize("name", ["embedded", "embedded_real"])
def test_embedded_is_table_4_with_a_profile_per_tracker(name):
    exp = load_experiment(ROOT / f"experiments/{name}.yaml")
    roles = {}
    for r in exp.runs:
        proto = r.resolved["protocol"]
        role = {"vot_rt": "embedded"}.get(proto["name"], proto["name"])
        roles.setdefault((r.tracker.name, is_mata(r.resolved)), set()).add(role)
        assert r.occlusion is not None
        if role == "eop":
            assert proto["tracker_hz"] == "profile" and proto["tracker_latency"] == "period"
            prof = read_profile(proto["latency_profile"])
            assert prof.machine["tracker"] == r.tracker.name  # each tracker its own profile
            assert 7.5 < prof.block("tracker").rate_hz < 12.5  # around the paper's ~10 Hz device
            scales = {x.resolved["protocol"].get("time_scale") for x in exp.runs
                      if x.resolved["protocol"]["name"] == "vot_rt"}
            assert scales == {prof.machine["time_scale"]}  # the emulated device is the same one
    assert all(v == {"embedded", "eop", "ltp"} for v in roles.values())
    assert len(roles) == 4


def test_embedded_roles_match_the_report():
    exp = load_experiment(ROOT / "experiments/embedded.yaml")

    class _Run:  # what embedded_role reads
        def __init__(self, cfg):
            self.config = cfg

    assert sorted(embedded_role(_Run(r.resolved)) for r in exp.runs) == sorted(["Embedded", "EOP", "LTP"] * 4)


def test_quickstart_is_the_readme_job():
    """Every shipped tracker that needs no torch, alone and in MATA, LTP and EOP@10Hz; the
    ONNX trackers are optional (skipped with a line when their model files are not found)."""
    exp = load_experiment(ROOT / "experiments/quickstart.yaml")
    keys = {key(r) for r in exp.runs}
    assert keys == {("synthetic", True, p, t, m) for p in ("LTP", "EOP @ 10 Hz") for m in (False, True)
                    for t in ("kcf", "vittrack", "nanotrack")}
    assert {r.tracker.name for r in exp.runs if r.optional} == {"vittrack", "nanotrack"}


def test_shipped_experiments_are_found_by_name(tmp_path, monkeypatch):
    """From any folder (a wheel install has no experiments/ beside it), `quickstart` and
    `experiments/quickstart.yaml` name the shipped file; a file that exists wins."""
    monkeypatch.chdir(tmp_path)
    shipped = find_experiment("quickstart")
    assert shipped.is_file() and shipped.name == "quickstart.yaml"
    assert find_experiment("experiments/quickstart.yaml") == shipped
    (tmp_path / "quickstart").mkdir()   # a run's output folder of that name does not hide it (wheel QA)
    assert find_experiment("quickstart") == shipped
    (tmp_path / "results" / "quickstart").mkdir(parents=True)   # a run folder given by mistake is not run (review)
    assert find_experiment("results/quickstart") == Path("results/quickstart")
    (tmp_path / "experiments").mkdir()
    own = tmp_path / "experiments" / "quickstart.yaml"
    own.write_text("dataset: {name: synthetic}\ntracker: {name: kcf}\n")
    assert find_experiment("experiments/quickstart.yaml") == Path("experiments/quickstart.yaml")
    assert {p.stem for p in shipped_experiments()} >= {"quickstart", "protocols", "challenges"}


def test_a_shipped_experiment_finds_its_own_files_from_any_folder(tmp_path, monkeypatch):
    """Wheel-install QA: `mata-eval validate embedded` outside the clone looked for its timing
    profiles (experiments/profiles/...) in the current folder; from the clone's root the file's
    configuration (and its hash) is as before."""
    def profiles() -> list[str]:
        return [r.resolved["protocol"]["latency_profile"] for r in load_experiment("embedded").runs
                if r.resolved["protocol"].get("latency_profile")]

    from mata_eval.run.runner import model_files

    root = find_experiment("embedded").resolve().parents[1]
    monkeypatch.chdir(root)
    hashes = {r.name: r.config_hash for r in load_experiment("embedded").runs}
    assert profiles() and all(p.startswith("experiments/profiles/") for p in profiles())
    monkeypatch.chdir(tmp_path)   # (review: the path made absolute put the install folder into the hash)
    exp = load_experiment("embedded")
    assert {r.name: r.config_hash for r in exp.runs} == hashes
    files = [model_files(r)["latency_profile"] for r in exp.runs if r.resolved["protocol"].get("latency_profile")]
    assert files and all(Path(f["path"]).is_file() and Path(f["path"]).is_relative_to(root) for f in files)
