"""Every config field's admissible values, declared once beside it (``minatt_jax.fields``), hold
for every way in: values drawn inside and outside each field's rule go through ``--set``'s
parser and the dataclasses; an admissible value is accepted (or refused by a cross-field rule
that names its group), an inadmissible one is refused with one line naming the field, in the
Python API (ValueError) and the CLI (exit 2) alike."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from minatt_jax import api, fields
from minatt_jax.agents import registry
from minatt_jax.cli import main
from minatt_jax.config import PRESETS, TrainConfig, apply_overrides, resolve, with_overrides

BASE = PRESETS["smoke"]
# One smoke configuration per built-in agent: together they hold every built-in settings group.
BASES = {algo: with_overrides(BASE, algo=algo, env="point_robot" if algo == "mamba" else None)
         for algo in registry.BUILTIN}  # fmt: skip
# Where a group's field is drawn: the first agent that owns the group.
OWNER = {}
for _algo, _config in BASES.items():
    for _group in _config.group_names:
        OWNER.setdefault(_group, _algo)


def declared(config: TrainConfig) -> list[tuple[str, fields.Rule]]:
    """(dotted name, rule) of every field of ``config`` with a declared rule, its groups'
    included."""
    out = [(f.name, fields.rule_of(f)) for f in dataclasses.fields(config)
           if fields.rule_of(f) is not None]  # fmt: skip
    for group in config.group_names:
        out += [
            (f"{group}.{f.name}", fields.rule_of(f))
            for f in dataclasses.fields(getattr(config, group))
            if fields.rule_of(f)
        ]
    return out


FIELDS = sorted({item for algo, c in BASES.items() for item in declared(c)
                 if "." not in item[0] or OWNER[item[0].split(".")[0]] == algo},
                key=lambda item: item[0])  # fmt: skip


def base_of(name: str) -> TrainConfig:
    """The smoke configuration of the agent that owns the field ``name``."""
    return BASES[OWNER[name.split(".")[0]]] if "." in name else BASE


def test_every_group_declares_its_fields():
    """Each group's every field has a rule (a field added without one fails here)."""
    names = {name for name, _ in FIELDS}
    for config in BASES.values():
        for group in config.group_names:
            for inner in dataclasses.fields(getattr(config, group)):
                assert f"{group}.{inner.name}" in names, f"{group}.{inner.name} has no rule"
    assert len(FIELDS) > 80


def numbers(rule: fields.Rule, inside: bool) -> st.SearchStrategy:
    """Numbers inside ``rule``'s bounds, or just outside them (and non-finite ones)."""
    low = rule.ge if rule.ge is not None else rule.gt
    high = rule.le if rule.le is not None else rule.lt
    whole = rule.kind is int
    if inside:
        lo = low if low is not None else -1e6
        hi = high if high is not None else 1e6
        if whole:
            return st.integers(math.ceil(lo), math.floor(hi)).filter(rule.admits)
        return st.floats(lo, hi, allow_nan=False).filter(rule.admits)
    outside = []
    if low is not None:
        edge = st.just(low) if rule.gt is not None else st.just(low - 1 if whole else low - 1e-3)
        outside.append(edge)
    if high is not None:
        edge = st.just(high) if rule.lt is not None else st.just(high + 1 if whole else high + 1)
        outside.append(edge)
    if not whole:
        outside.append(st.sampled_from([math.nan, math.inf, -math.inf]))
    return st.one_of(outside) if outside else st.nothing()


def values(rule: fields.Rule, inside: bool) -> st.SearchStrategy:
    if rule.choices is not None:
        return st.sampled_from(rule.choices) if inside else st.just("no-such-choice")
    if rule.kind is bool:
        return st.booleans() if inside else st.just("maybe")
    if rule.kind is tuple:
        size = rule.length if rule.length is not None else None
        low_size = size if size is not None else (rule.min_length or 0)
        items = numbers(rule.item, inside=True) if rule.item else st.integers(1, 4)
        if inside:
            return st.lists(items, min_size=low_size, max_size=size or low_size + 3).map(tuple)
        wrong_size = st.lists(items, min_size=0, max_size=max(low_size - 1, 0)).map(tuple)
        if size is not None:
            wrong_size = st.lists(items, min_size=size + 1, max_size=size + 2).map(tuple)
        bad_item = (st.lists(numbers(rule.item, inside=False), min_size=1, max_size=2).map(tuple)
                    if rule.item else st.nothing())  # fmt: skip
        options = [bad_item] + ([wrong_size] if (size is not None or low_size > 0) else [])
        return st.one_of(options)
    if rule.kind is str:
        return st.nothing()
    return numbers(rule, inside)


def as_text(value) -> str:
    """A value in ``--set``'s syntax."""
    if isinstance(value, tuple):
        return ",".join(as_text(v) for v in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


@st.composite
def drawn(draw):
    name, rule = draw(st.sampled_from(FIELDS))
    inside = draw(st.booleans())
    strategy = values(rule, inside)
    if strategy.is_empty:
        inside = True
        strategy = values(rule, True)
    value = draw(strategy)
    if rule.optional and inside and draw(st.booleans()):
        value = None
    return name, rule, inside, value


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(drawn())
def test_each_field_accepts_its_values_and_refuses_the_rest_by_name(case):
    name, rule, inside, value = case
    text = "none" if value is None else as_text(value)
    group = name.split(".")[0] + "." if "." in name else ""
    try:
        config = resolve(apply_overrides(base_of(name), [f"{name}={text}"]))
    except ValueError as e:
        message = str(e)
        assert "\n" not in message
        if inside:  # only a cross-field rule may refuse an admissible value: it names the group
            assert group and group in message or name in message, (name, value, message)
        else:
            assert name in message, (name, value, message)
        return
    assert inside, f"{name}={text} was accepted"
    got = config
    for part in name.split("."):
        got = getattr(got, part)
    assert rule.admits(got)


@settings(max_examples=25, deadline=None)
@given(st.sampled_from(FIELDS).flatmap(
    lambda f: values(f[1], inside=False).map(lambda v: (f[0], v))))  # fmt: skip
def test_the_cli_refuses_an_inadmissible_value_in_one_line(capsys_case):
    name, value = capsys_case
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            base = base_of(name)
            status = main(["train", "--preset", "smoke", "--algo", base.algo, "--env", base.env,
                           "--set", f"{name}={as_text(value)}",
                           "--out", "/nonexistent-minatt-jax/run"])  # fmt: skip
        except SystemExit as e:
            status = e.code
    lines = err.getvalue().strip().splitlines()
    assert status == 2 and len(lines) == 1 and name in lines[0], (name, value, lines)


@pytest.mark.parametrize(
    "field, value",
    [("sac.gamma", 1.5), ("sac.actor_lr", -1e-3), ("sac.hidden", ()), ("mb.real_ratio", 2.0)],
)
def test_the_python_api_raises_the_same_message(field, value):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        api.make_config(
            preset="smoke", algo=OWNER[field.split(".")[0]], **{field.replace(".", "_"): value}
        )


def test_values_at_the_edges_of_their_rules_train_a_chunk(tmp_path):
    """Admissible edges (gamma 0, tau 1, an actor learning rate of 0, MA's smallest interval
    and subsample) are not only accepted: they train."""
    overrides = ["sac.gamma=0", "sac.tau=1", "sac.actor_lr=0", "ma.interval=1", "ma.subsample=0"]
    run = api.train(preset="smoke", total_steps=300, ma_alpha=1.0, out=str(tmp_path / "edge"),
                    overrides=overrides, log=lambda _: None)  # fmt: skip
    assert run.metrics[-1]["step"] == 300


def _train_or_diverge(config: TrainConfig, out: str) -> None:
    """Trains ``config`` for its smoke length; a drawn value may make training go non-finite,
    which must end in the NaN guard's one-line error, never in another exception."""
    from minatt_jax import runner
    from minatt_jax.run_files import DivergedError

    try:
        runner.train(config, out, log=lambda _: None)
    except DivergedError as e:
        assert "\n" not in str(e) and "diverged at step" in str(e)
        return
    records = runner.read_metrics(out)
    assert records and records[-1]["step"] == config.planned_steps


def _swept_without_recompiling() -> list[tuple[str, fields.Rule]]:
    from minatt_jax.agents import registry

    swept = set(registry.get("sac").hyper.values())
    return [(name, rule) for name, rule in FIELDS if name in swept]


@pytest.mark.slow
@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_admissible_values_of_the_swept_fields_train_a_smoke_chunk(tmp_path_factory, data):
    """Every admissible draw of the fields a population sweeps (MA's weight, the learning rates)
    trains a 300-step smoke chunk or stops in the NaN guard; one compiled program serves all."""
    overrides = [f"{name}={as_text(data.draw(values(rule, True), label=name))}"
                 for name, rule in _swept_without_recompiling()]  # fmt: skip
    config = resolve(apply_overrides(BASE, [*overrides, "total_steps=300", "eval_every=300"]))
    _train_or_diverge(config, str(tmp_path_factory.mktemp("drawn")))


@pytest.mark.extended
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(drawn())
def test_an_admissible_value_of_any_field_trains_a_smoke_chunk(tmp_path_factory, case):
    """Any field's admissible value (one field at a time, the others at the smoke preset) is
    refused by a cross-field rule naming its group, or trains a smoke chunk (most of them
    compile their own program: an extended test)."""
    name, rule, inside, value = case
    if not inside:
        return
    text = "none" if value is None else as_text(value)
    try:
        config = resolve(apply_overrides(base_of(name), [f"{name}={text}"]))
        config = resolve(apply_overrides(config, ["total_steps=300", "eval_every=300"]))
    except ValueError as e:
        assert "\n" not in str(e)
        return
    sizes = value if isinstance(value, tuple) else (value,)
    if any(isinstance(v, int) and not isinstance(v, bool) and v > 512 for v in sizes):
        return  # a size this large (networks, batches, episodes) is beyond a test's memory
    _train_or_diverge(config, str(tmp_path_factory.mktemp("drawn")))
