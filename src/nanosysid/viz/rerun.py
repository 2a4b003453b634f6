"""Rerun recordings of a flight: the measured trajectory and pose in 3D, each model's rollouts
from a regular subset of starts, and time series of true and predicted signals and errors.

Every entity is logged as whole columns (``rerun.send_columns``), one call per entity, and
the layout travels in the file as its default blueprint, so the recording opens ready to read
(``rerun reports/rerun/<flight>.rrd``). Nothing opens a viewer here.

Entities, for a flight of T samples, horizon H and S rollout starts:

- ``world/trajectory``: the measured path (static); ``world/drone``: its pose, T rows;
- ``world/rollouts/truth`` and ``world/rollouts/<model>``: at each start, the next H
  positions measured and predicted, S rows;
- ``signals/<q>/truth``: the measured signal, T rows; ``signals/<q>/<model>``: the
  H-step-ahead prediction ``ŷ(t | t-H)``, T - H rows (``q`` in p, v, R, w; R as roll,
  pitch, yaw in degrees);
- ``errors/<q>/<model>``: the error of that prediction (norm; geodesic angle for R), T - H rows.
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import os
import shutil
import uuid
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np

from nanosysid import metrics
from nanosysid.dataio import Flight, atomic_file
from nanosysid.protocol import Kept
from nanosysid.viz import rrd
from nanosysid.viz.signals import SIGNALS, model_color, readable

__all__ = ["write_recording", "kept_of", "APPLICATION_ID"]

APPLICATION_ID = "nanosysid"


def kept_of(pred: np.ndarray, stride: int) -> Kept:
    """:class:`Kept` rollouts from whole predictions ``(N, H, 13)`` from every start
    (:func:`nanosysid.protocol.predictions`), whole rollouts every ``stride`` starts."""
    stride = max(1, int(stride))
    return Kept(last=pred[:, -1], paths=pred[::stride], stride=stride)


def _rgb(color: str) -> list[int]:
    return [int(color[i:i + 2], 16) for i in (1, 3, 5)]


def _blueprint(models: list[str], notes: bool = False):
    import rerun.blueprint as rrb

    series = [rrb.TimeSeriesView(origin=f"signals/{k}", name=f"{SIGNALS[k][0]} [{SIGNALS[k][1]}]")
              for k in SIGNALS]
    errors = [rrb.TimeSeriesView(origin=f"errors/{k}", name=f"error of {SIGNALS[k][0]} [{metrics.UNITS[k]}]")
              for k in SIGNALS]
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="trajectory, pose and rollouts"),
            rrb.Vertical(rrb.Tabs(*series, name="signals"), rrb.Tabs(*errors, name="errors"),
                         *([rrb.TextDocumentView(origin="discovery", name="discovery's verdicts")] if notes else [])),
            column_shares=[1, 1],
        ),
        rrb.TimePanel(state="expanded"),
        collapse_panels=True,
    )
    # views and containers are named by ids the SDK draws at random: number them in layout order
    ids = itertools.count(1)

    def number(item) -> None:
        item.id = uuid.UUID(int=next(ids))
        for child in getattr(item, "contents", None) or ():
            if hasattr(child, "id"):  # a view or container, not a view's query of entities
                number(child)

    number(blueprint.root_container)
    return blueprint


# s: a flush waits no longer (the SDK's file writer, stopped by a full disk, leaves it waiting
# for ever)
FLUSH_TIMEOUT = 120.0
_FULL = 1 << 20  # bytes free below which a failed write is the disk's


@contextlib.contextmanager
def _disk_full_named(tmp: Path) -> Iterator[None]:
    """The SDK's file writer, stopped by a full disk, says so only in its log and raises a
    RuntimeError ("File-writer thread shut down prematurely"): read as the full disk it is."""
    try:
        yield
    except RuntimeError:
        if shutil.disk_usage(tmp.parent).free < _FULL:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp)) from None
        raise


def write_recording(flight: Flight, rollouts: Mapping[str, Kept], path: Path, *,
                    verdicts: str | None = None) -> None:
    """Write ``path`` (``.rrd``) for one flight.

    Args:
        flight: The measured flight.
        rollouts: Each model's rollouts on it (:class:`nanosysid.protocol.Kept`, as the
            evaluate stage keeps them, or :func:`kept_of` from whole predictions); the 3D
            rollouts are drawn from their starts, which must be the same for every model.
        path: Output file; written to a temporary name, then renamed.
        verdicts: Discovery's verdicts (markdown), shown beside the signals.
    """
    import rerun as rr

    first = next(iter(rollouts.values()))
    n, H, starts = len(first.last), first.paths.shape[1], first.starts
    if any(len(k.last) != n or k.stride != first.stride or k.paths.shape[1] != H for k in rollouts.values()):
        raise ValueError(f"flight {flight.name}: the models' rollouts differ in windows, horizon or stride")
    t = flight.t - flight.t[0]
    # the recording id is the flight's, so the same flight and models give the same file
    recording_id = f"{APPLICATION_ID}-{flight.name}"
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id, send_properties=False)

    def static(entity: str, archetype) -> None:
        # flushed at once: the SDK's batcher thread would otherwise interleave these chunks with
        # the columns sent directly, in an order that varies from run to run
        rec.log(entity, archetype, static=True)
        rec.flush(timeout_sec=FLUSH_TIMEOUT)

    with atomic_file(Path(path)) as tmp, _disk_full_named(tmp):
        rec.save(tmp, default_blueprint=_blueprint(list(rollouts), notes=verdicts is not None))
        if verdicts is not None:
            static("discovery", rr.TextDocument(verdicts, media_type=rr.MediaType.MARKDOWN))
        every = [rr.TimeColumn("time", duration=t)]
        predicted = [rr.TimeColumn("time", duration=t[H:H + n])]
        at_starts = [rr.TimeColumn("time", duration=t[starts])]

        static("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP)
        static("world/trajectory", rr.LineStrips3D([flight.y[:, :3]], colors=[[150, 150, 150]], radii=0.002))
        rec.send_columns("world/drone", indexes=every,
                         columns=rr.Transform3D.columns(translation=flight.y[:, :3], quaternion=flight.y[:, 6:10]))
        # body axes of the drone, 8 cm long: x red, y green, z blue
        static("world/drone/axes", rr.Arrows3D(vectors=0.08 * np.eye(3),
                                               colors=[[230, 40, 40], [40, 180, 40], [40, 80, 230]]))

        # the measured next H positions from each start, then each model's prediction of them
        truth_paths = np.stack([flight.y[s:s + H + 1, :3] for s in starts])  # (S, H+1, 3)
        static("world/rollouts/truth", rr.LineStrips3D.from_fields(colors=_rgb(model_color("truth")), radii=0.003))
        rec.send_columns("world/rollouts/truth", indexes=at_starts,
                         columns=rr.LineStrips3D.columns(strips=list(truth_paths)))
        for i, (name, kept) in enumerate(rollouts.items()):
            paths = np.concatenate([flight.y[starts, None, :3], kept.paths[:, :, :3]], axis=1)  # (S, H+1, 3)
            static(f"world/rollouts/{name}", rr.LineStrips3D.from_fields(colors=_rgb(model_color(name, i)),
                                                                        radii=0.003))
            rec.send_columns(f"world/rollouts/{name}", indexes=at_starts,
                             columns=rr.LineStrips3D.columns(strips=list(paths)))

        truth = readable(flight.y)
        for k, (label, _, axes) in SIGNALS.items():
            static(f"signals/{k}/truth", rr.SeriesLines(names=[f"{a} measured" for a in axes],
                                                        colors=[_rgb(model_color("truth"))] * 3))
            rec.send_columns(f"signals/{k}/truth", indexes=every, columns=rr.Scalars.columns(scalars=truth[k]))
        for i, (name, kept) in enumerate(rollouts.items()):
            y_hat = kept.last  # (n, 13): ŷ(t | t-H) for t = H .. H + n - 1
            err = metrics.errors(flight.y[None, H:H + n], y_hat[None])
            shown = readable(y_hat)
            color = _rgb(model_color(name, i))
            for k, (label, _, axes) in SIGNALS.items():
                static(f"signals/{k}/{name}", rr.SeriesLines(names=[f"{a} {name}" for a in axes], colors=[color] * 3))
                rec.send_columns(f"signals/{k}/{name}", indexes=predicted, columns=rr.Scalars.columns(scalars=shown[k]))
                static(f"errors/{k}/{name}", rr.SeriesLines(names=[name], colors=[color]))
                rec.send_columns(f"errors/{k}/{name}", indexes=predicted,
                                 columns=rr.Scalars.columns(scalars=err[k][0]))
        rec.flush(timeout_sec=FLUSH_TIMEOUT)
        rec.disconnect()
        # the SDK's random ids and wall-clock times replaced: the same flight and models, the same bytes
        data = rrd.with_footer(rrd.canonical(tmp.read_bytes(), recording_id))
        rrd.check(data)  # a whole stream, or nothing is written
        tmp.write_bytes(data)
