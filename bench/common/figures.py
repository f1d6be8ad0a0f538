"""A bench figure: a value next to a baseline measured in the same run, printed as one JSON line
when it is recorded ({"name", "value", "unit", "baseline", "ratio", "baseline_name", "target",
"note"}) and in one table at the end of the run (bench/run.py and the groups it runs).
"""

import json
import math

FIGURES = []  # every figure recorded in this process, in order


class Figure:
    __slots__ = ("name", "value", "unit", "baseline", "baseline_name", "target", "note")

    def __init__(self, name, value, unit, baseline, baseline_name, target="", note=""):
        self.name, self.value, self.unit = name, value, unit
        self.baseline, self.baseline_name = baseline, baseline_name
        self.target, self.note = target, note

    @property
    def ratio(self):
        if self.value is None or not self.baseline:
            return None
        return self.value / self.baseline

    def as_json(self):
        return {"name": self.name, "value": _round(self.value), "unit": self.unit,
                "baseline": _round(self.baseline), "ratio": _round(self.ratio, 3),
                "baseline_name": self.baseline_name, "target": self.target, "note": self.note}


def _round(value, digits=1):
    if value is None:
        return None
    if isinstance(value, float):
        return round(value, digits) if abs(value) >= 1 or digits > 1 else round(value, 3)
    return value


def record(*args, **kwargs):
    figure = Figure(*args, **kwargs)
    FIGURES.append(figure)
    print(json.dumps(figure.as_json()), flush=True)
    return figure


def percentile(values, fraction):
    ordered = sorted(values)
    if not ordered:
        return None
    index = min(len(ordered) - 1, max(0, int(math.ceil(fraction * len(ordered))) - 1))
    return ordered[index]


def print_table():
    headers = ("figure", "value", "unit", "baseline", "ratio", "target", "baseline is")
    rows = []
    for f in FIGURES:
        rows.append((f.name, _text(f.value), f.unit, _text(f.baseline),
                     "-" if f.ratio is None else "%.3f" % f.ratio, f.target or "-",
                     f.baseline_name))
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
              for i, h in enumerate(headers)]
    print()
    print("| " + " | ".join(h.ljust(w) for h, w in zip(headers, widths)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for row in rows:
        print("| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |")
    notes = [(f.name, f.note) for f in FIGURES if f.note]
    for name, note in notes:
        print("  %s: %s" % (name, note))


def _text(value):
    if value is None:
        return "-"
    if isinstance(value, float):
        return "%.3f" % value if abs(value) < 10 else "%.0f" % value
    return str(value)
