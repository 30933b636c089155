"""Declared plugin parameters: validation of YAML values against the Params dataclass."""

import dataclasses
from dataclasses import dataclass
from typing import Literal

import pytest

from mata_eval.core.errors import ConfigError
from mata_eval.params import build_params, describe, param, parse_key_values


@dataclass(frozen=True)
class P:
    rate: float = param(10.0, "tracker rate in Hz")
    grid: int = param(16, "points per side")
    model: Literal["cv", "ca", "cj"] = param("cv", "motion model")
    path: str | None = param(None, "model file")
    sizes: list[int] = param([1, 2], "sizes")
    pair: tuple[float, float] = param((0.5, 0.5), "a pair")
    on: bool = param(True, "switch")
    port: Literal["5.0", "5.1"] = param("5.0", "a choice that YAML reads as a number")


def test_defaults_and_coercion():
    p = build_params(P, {"rate": 5, "sizes": [3], "pair": [1, 2]})
    assert p.rate == 5.0 and isinstance(p.rate, float)
    assert p.sizes == [3] and p.pair == (1.0, 2.0) and p.grid == 16 and p.path is None


def test_a_yaml_number_that_spells_a_choice_is_that_choice():
    import yaml   # `port: 5.1` is a float in YAML
    assert build_params(P, yaml.safe_load("port: 5.1")).port == "5.1"
    assert build_params(P, yaml.safe_load("port: '5.0'")).port == "5.0"


@pytest.mark.parametrize("values, fragment", [
    ({"rate": "fast"}, "expected float, got 'fast'"),
    ({"grid": 1.5}, "expected int"),
    ({"grid": True}, "expected int"),
    ({"on": 1}, "expected bool"),
    ({"model": "kf"}, "expected one of 'cv', 'ca', 'cj'"),
    ({"port": 5.2}, "expected one of '5.0', '5.1', got 5.2"),
    ({"port": True}, "expected one of '5.0', '5.1'"),
    ({"pair": [1]}, "expected 2 values"),
    ({"sizes": [1, "x"]}, "expected int"),
    ({"colour": 1}, "unknown parameter 'colour'; this plugin takes: grid, model, on, pair, path, port, rate, sizes"),
])
def test_bad_values_name_key_and_expectation(values, fragment):
    with pytest.raises(ConfigError) as err:
        build_params(P, values, ("tracker",), lambda kp: "exp.yaml:7")
    msg = str(err.value)
    assert fragment in msg
    assert msg.startswith("exp.yaml:7: tracker.")


def test_describe_lists_type_default_doc():
    info = {p.name: p for p in describe(P)}
    assert info["rate"].type == "float" and info["rate"].default == 10.0
    assert info["rate"].doc == "tracker rate in Hz"
    assert info["path"].type == "str or null"
    assert info["sizes"].default == [1, 2]
    assert not info["rate"].required

    @dataclass(frozen=True)
    class Needs:
        path: str = dataclasses.field(metadata={"doc": "a file"})

    (need,) = describe(Needs)
    assert need.required and need.default is None   # `list -v` says "(required)", not "= None"


@dataclass(frozen=True)
class Checked:
    lo: float = param(0.0, "lower bound")
    hi: float = param(1.0, "upper bound")

    def __post_init__(self):
        if self.hi <= self.lo:
            raise ValueError(f"hi must be greater than lo, got lo={self.lo}, hi={self.hi}")


def test_plugin_cross_field_check_gets_the_location():
    with pytest.raises(ConfigError, match=r"^exp.yaml:3: estimator: hi must be greater than lo"):
        build_params(Checked, {"lo": 2, "hi": 1}, ("estimator",), lambda kp: "exp.yaml:3")


@dataclass(frozen=True)
class KeyChecked:
    shapes: list[str] = param(["circle"], "occluder shapes")

    def __post_init__(self):
        if "hexagon" in self.shapes:
            raise ConfigError("", ("occlusion", "shapes"), "unknown shape 'hexagon'")


def test_plugin_check_naming_a_key_gets_that_keys_line():
    lines = {("occlusion",): "exp.yaml:5", ("occlusion", "shapes"): "exp.yaml:6"}
    with pytest.raises(ConfigError) as err:
        build_params(KeyChecked, {"shapes": ["hexagon"]}, ("occlusion",), lambda kp: lines[tuple(kp)])
    assert str(err.value) == "exp.yaml:6: occlusion.shapes: unknown shape 'hexagon'"


def test_command_line_key_values_are_read_as_yaml():
    # what `mata-eval eval --set` and the benchmarks' --param / --grid-lk hand to build_params
    got = parse_key_values(["a=1", "b=0.5", "c=true", "d=null", "e=x=y", "f=[1, 2]", "g=: bad"])
    assert got == {"a": 1, "b": 0.5, "c": True, "d": None, "e": "x=y", "f": [1, 2], "g": ": bad"}
    for bad in ("novalue", "=3"):
        with pytest.raises(ValueError, match="expected KEY=VALUE"):
            parse_key_values([bad])


def test_a_number_yaml_reads_as_text_gets_a_hint():
    """YAML 1.1 reads 3e1 (no dot, no exponent sign) as a string: the message says so (QA pass:
    'expected float, got '3e1' (str)' read as nonsense to whoever typed a number)."""
    import yaml

    @dataclass(frozen=True)
    class Rate:
        fps: float = param(30.0, "frames per second")

    with pytest.raises(ConfigError, match=r"YAML reads 3e1 as text .*write 30.0 or 3.0e\+01"):
        build_params(Rate, yaml.safe_load("{fps: 3e1}"))
    with pytest.raises(ConfigError, match=r"got 'fast' \(str\)$"):
        build_params(Rate, {"fps": "fast"})
    # YAML spells NaN and the infinities .nan, .inf, -.inf (QA pass: the hint said 'write nan or nan')
    for typed, spelling in (("nan", ".nan"), ("inf", ".inf"), ("-Infinity", "-.inf")):
        with pytest.raises(ConfigError, match=rf"YAML reads {typed} as text \(write {spelling}\)$"):
            build_params(Rate, yaml.safe_load(f"{{fps: {typed}}}"))
        assert repr(build_params(Rate, yaml.safe_load(f"{{fps: {spelling}}}")).fps) == repr(float(typed))   # the spelling works

