"""What ``slipsense models`` prints: the registered models and the shipped detectors, as two tables.

Fast on purpose (about 2 s, most of it importing torch): no model is initialised
(:func:`default_parameter_counts`) and no weight is loaded (a shipped detector is described from its
checkpoint's stored config).
"""

from __future__ import annotations

import inspect
from typing import Any, Iterable, Mapping, Sequence

#: In-place operations that only change a tensor's values (what a constructor initialises weights with).
_VALUE_ONLY = frozenset(
    {"normal_", "uniform_", "zero_", "fill_", "copy_", "erfinv_", "mul_", "add_", "sub_", "div_", "clamp_"}
    | {"exponential_", "bernoulli_", "random_", "fill_diagonal_"}
)


def detector_promise(info: Mapping[str, Any]) -> str:
    """What a shipped detector promises about held grasps, in one line: the one place that reads it."""
    from slipsense.measures.promise import promise_text

    return promise_text(info.get("operating_point"))


def default_parameter_counts() -> dict[str, int]:
    """``{name: trainable parameters}`` of every registered model at its default settings.

    Each model is built with every ``torch.nn.init`` function and in-place value operation skipped:
    the counts need shapes, not values, and the uninitialised weights of STNet at the paper's size
    (127 M) stay untouched pages. (Building on the meta device instead imports torch's reference
    implementations, another 2 s.)"""
    import torch
    from torch.overrides import TorchFunctionMode

    from slipsense.models import available, count_parameters, model_class

    class SkipValues(TorchFunctionMode):
        def __torch_function__(self, func, types, args=(), kwargs=None):
            kwargs = kwargs or {}
            if getattr(func, "__module__", "") == "torch.nn.init" or getattr(func, "__name__", "") in _VALUE_ONLY:
                return args[0] if args else next(iter(kwargs.values()))  # the tensor, unchanged
            return func(*args, **kwargs)

    counts = {}
    with torch.no_grad():
        for name in available():
            with SkipValues():
                model = model_class(name)()
            counts[name] = count_parameters(model)
            del model
    return counts


def cameras(info: Mapping[str, Any]) -> str:
    """Cameras a checkpoint's model takes per push: its ``sensors`` setting, else the model's default;
    "each" for a clip model, which judges every camera's clips on its own."""
    from slipsense.models import registered
    from slipsense.models.base import setting_default

    sensors = info["model_config"].get("sensors")
    if sensors is None and info["model"] in registered():
        sensors = setting_default(registered()[info["model"]], "sensors")
    return "each" if sensors is None else str(sensors)


def table(header: Sequence[str], rows: Iterable[Sequence[str]], right: Sequence[int] = ()) -> str:
    """Aligned columns, two spaces apart; columns ``right`` right-aligned; the last one not padded."""
    rows = [tuple(header)] + [tuple(str(c) for c in r) for r in rows]
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]

    def line(row: Sequence[str]) -> str:
        cells = [c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths))]
        cells[-1] = row[-1].rjust(widths[-1]) if len(row) - 1 in right else row[-1]
        return "  ".join(cells).rstrip()

    return "\n".join(line(r) for r in rows)


def models_text() -> str:
    """Both tables, as ``slipsense models`` prints them."""
    from slipsense.checkpoint import read_info
    from slipsense.models import model_class
    from slipsense.resources import DEFAULT_DETECTOR, ONE_SENSOR_DETECTOR, shipped_model, shipped_models

    counts = default_parameter_counts()
    docs = {name: inspect.getdoc(model_class(name)) or "" for name in counts}  # what it is, in its own words
    registered_rows = [
        (m, docs[m].splitlines()[0].rstrip(".") if docs[m] else "-", f"{n:,}") for m, n in counts.items()
    ]
    shipped_rows = []
    for name in shipped_models():
        info = read_info(shipped_model(name))
        sensor = info.get("sensor") or {}
        fps = sensor.get("fps")
        row = (name, info["model"], sensor.get("name", "-"), cameras(info), "-" if fps is None else f"{fps:g}")
        shipped_rows.append((*row, detector_promise(info)))
    registered = table(("model", "what it is", "parameters"), registered_rows, right=(2,))
    shipped = table(("detector", "model", "sensor", "cameras", "frames/s", "promise"), shipped_rows, right=(3, 4))
    head = (
        f"Shipped detectors (`SlipDetector.pretrained(NAME)`; the default: {DEFAULT_DETECTOR}, "
        f"for one camera {ONE_SENSOR_DETECTOR}; files: {shipped_model(DEFAULT_DETECTOR).parent}):"
    )
    return "\n".join(
        ["Registered models (`--model NAME`; parameters at default settings):", registered, "", head, shipped]
    )
