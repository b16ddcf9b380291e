"""Admissible values of a configuration field, declared once beside the field.

A config dataclass declares a field as ``gamma: float = setting(0.99, ge=0, lt=1)``: the default
and the rule together. Its ``__post_init__`` calls ``check(self, "sac")``, which enforces every
declared rule and raises ``ValueError`` with one line naming the field (``sac.gamma must be in
[0, 1), got 1.5``). Every way a configuration is made goes through the dataclass constructor
(the CLI's flags, ``--set``, ``--sweep``, the Python API, a ``config.json`` read back), so every
one of them meets the same rule and the same message; cross-field rules (a schedule's order, one
weight decay per layer) stay in the ``__post_init__`` beside the call. ``rule_of`` hands the
rule to tests that draw values inside and outside it.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import numbers
import typing
from typing import Any

_RULE = "minatt_jax.rule"
_WHY = "minatt_jax.why"


@dataclasses.dataclass(frozen=True)
class Rule:
    """What a field admits: a number's bounds (``ge``/``gt``/``le``/``lt``), a string's
    ``choices``, a tuple's ``length`` / ``min_length`` with a rule for each ``item``, and whether
    ``None`` (a derived default) is allowed. Numbers are finite; booleans are booleans."""

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple[Any, ...] | None = None
    length: int | None = None
    min_length: int | None = None
    item: Rule | None = None
    optional: bool = False
    kind: type | None = None  # bool, int, float, str or tuple: set by ``setting`` from the default

    def describe(self) -> str:
        """The admissible values in words: 'in [0, 1)', 'one of ('sac', 'vpg')', ..."""
        parts = []
        if self.choices is not None:
            parts.append(f"one of {self.choices}")
        elif self.kind is bool:
            parts.append("true or false")
        elif self.kind is str:
            parts.append("a name")
        elif self.kind is tuple:
            size = (f"{self.length} values" if self.length is not None else
                    f"at least {self.min_length} value{'s' * (self.min_length != 1)}"
                    if self.min_length else "values")  # fmt: skip
            parts.append(size + (f", each {self.item.describe()}" if self.item else ""))
        else:
            parts.append(self._bounds())
        return " or ".join(parts) + (" (or None)" if self.optional else "")

    def _bounds(self) -> str:
        def num(x: float) -> str:
            return str(int(x)) if float(x).is_integer() else f"{x:g}"

        noun = "an integer" if self.kind is int else "a finite number"
        low = (self.ge, "[") if self.ge is not None else (self.gt, "(")
        high = (self.le, "]") if self.le is not None else (self.lt, ")")
        if low[0] is not None and high[0] is not None:
            return f"{noun} in {low[1]}{num(low[0])}, {num(high[0])}{high[1]}"
        if low[0] is not None:
            return f"{noun} {'>=' if low[1] == '[' else '>'} {num(low[0])}"
        if high[0] is not None:
            return f"{noun} {'<=' if high[1] == ']' else '<'} {num(high[0])}"
        return noun

    def admits(self, value: Any) -> bool:
        """Whether ``value`` is admissible."""
        if value is None:
            return self.optional
        if self.choices is not None:
            return value in self.choices
        if self.kind is bool:
            return isinstance(value, bool)
        if self.kind is str:
            return isinstance(value, str)
        if self.kind is tuple:
            if not isinstance(value, tuple):
                return False
            if self.length is not None and len(value) != self.length:
                return False
            if self.min_length is not None and len(value) < self.min_length:
                return False
            return self.item is None or all(self.item.admits(v) for v in value)
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        if self.kind is int and not isinstance(value, numbers.Integral):
            return False
        if not math.isfinite(value):
            return False
        return ((self.ge is None or value >= self.ge) and (self.gt is None or value > self.gt)
                and (self.le is None or value <= self.le)
                and (self.lt is None or value < self.lt))  # fmt: skip


def setting(default: Any, *, kind: type | None = None, why: str = "", **rule: Any) -> Any:
    """A dataclass field with ``default`` and its admissible values (``Rule``'s fields); the
    value's kind is the default's unless given (``kind=float`` for an optional number); ``why``
    says where the default comes from (``train --help`` prints it beside the value)."""
    if kind is None:
        kind = tuple if isinstance(default, tuple) else type(default)
    if "item" in rule and isinstance(rule["item"], dict):
        rule["item"] = Rule(**rule["item"])
    metadata = {_RULE: Rule(kind=kind, **rule), _WHY: why}
    return dataclasses.field(default=default, metadata=metadata)


def why_of(field: dataclasses.Field) -> str:
    """Where the field's default comes from ("" when not declared)."""
    return field.metadata.get(_WHY, "")


def rule_of(field: dataclasses.Field) -> Rule | None:
    """The rule declared with ``field`` (None: a nested config, or a field checked elsewhere)."""
    return field.metadata.get(_RULE)


def check(instance: Any, group: str) -> None:
    """Raises ValueError ("<group>.<field> must be <rule>, got <value>") for the first field of
    ``instance`` whose value its declared rule does not admit."""
    for field in dataclasses.fields(instance):
        rule = rule_of(field)
        value = getattr(instance, field.name)
        if rule is not None and not rule.admits(value):
            name = f"{group}.{field.name}" if group else field.name
            raise ValueError(f"{name} must be {rule.describe()}, got {value!r}")


def _meanings(cls: type) -> dict[str, str]:
    """One line of meaning per field, from the ``Attributes:`` section of ``cls``'s docstring
    (``name: text``, or ``a, b: text`` for several)."""
    doc = inspect.getdoc(cls) or ""
    meanings: dict[str, str] = {}
    in_attributes, current = False, []
    for line in doc.splitlines():
        if line.strip() == "Attributes:":
            in_attributes = True
            continue
        if not in_attributes:
            continue
        if line and not line.startswith(" "):
            break
        head = line.strip()
        names, sep, text = head.partition(": ")
        if (
            sep
            and line.startswith("  ")
            and not line.startswith("    ")
            and all(n.strip().isidentifier() for n in names.split(","))
        ):
            current = [n.strip() for n in names.split(",")]
            for n in current:
                meanings[n] = text.strip()
        elif current and head:
            for n in current:
                meanings[n] += " " + head
    return {k: v.split(". ")[0].rstrip(".") for k, v in meanings.items()}


def field_rows(instance: Any, group: str, skip: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """The settings of a config dataclass ``instance`` as rows ``{"name", "type", "rule",
    "default", "meaning", "why"}`` (its current values as the defaults; ``group`` prefixes the
    names)."""
    hints = typing.get_type_hints(type(instance))
    meanings = _meanings(type(instance))
    rows = []
    for field in dataclasses.fields(instance):
        if field.name in skip:
            continue
        rule = rule_of(field)
        hint = hints[field.name]
        rows.append({
            "name": f"{group}.{field.name}" if group else field.name,
            "type": getattr(hint, "__name__", None) or str(hint).replace("typing.", ""),
            "rule": rule.describe() if rule else "a registered name" if hint is str else "",
            "default": getattr(instance, field.name),
            "meaning": meanings.get(field.name, ""),
            "why": why_of(field),
        })  # fmt: skip
    return rows
