"""Planning jobs kept as files: each job the worker planned, the world it planned in (objects, attachments, the
map's voxels) and what came of it, one `.npz` per job, so a live cell's plans can be planned again offline, on
another machine or another version (`replanner bench replay DIR`). Written by a thread of its own: a job's
answer never waits for the disk."""

from __future__ import annotations

import json
import logging
import queue
import threading
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InvalidInputError
from ..model.geometry import Shape, shape_from_dict, shape_to_dict

log = logging.getLogger(__name__)

FORMAT = 1  # bumped when a field changes meaning
MAX_JOBS = 10_000  # files a recorder writes at most (a map of 30k voxels is ~100 kB compressed)
CONFIG = "config.json"  # the recording service's config, beside its jobs
QUEUE = 16  # jobs waiting for the disk; more are dropped (and counted) rather than slow the planner down


@dataclass
class RecordedJob:
    """A job as recorded: plan `start` -> `q_goal` within `deadline` [s] among `objects`, `attachments` and the
    map's voxel `keys` (N, 3) of `resolution` [m]; `outcome`: what the worker answered (ok, plan_s, error, ...)."""

    path: Path
    robot: str | None
    purpose: str
    start: np.ndarray
    q_goal: np.ndarray
    deadline: float
    padding: float | None
    planner: str | None
    objects: list[tuple[str, Shape, np.ndarray]]
    attachments: list[tuple[str, Shape, str, np.ndarray, tuple[str, ...], tuple[str, ...]]]
    keys: np.ndarray
    resolution: float
    outcome: dict
    heading: np.ndarray | None = None  # the joint velocity of the motion a replan was spliced onto (None: from rest)


def _meta(robot, job, snapshot, answer) -> dict:
    res, err = answer.result, answer.error
    occ = snapshot.occupancy
    return {
        "format": FORMAT,
        "robot": robot,
        "purpose": getattr(job.purpose, "value", str(job.purpose)),
        "deadline": job.deadline,
        "padding": job.padding,
        "planner": job.planner,
        "heading": None if (h := job.heading()) is None else np.asarray(h, float).tolist(),
        "resolution": None if occ is None else occ.resolution,
        "objects": [
            {"name": o.name, "shape": shape_to_dict(o.shape), "pose": np.asarray(o.pose).tolist()}
            for o in snapshot.objects.values()
        ],
        "attachments": [
            {
                "name": a.name,
                "shape": shape_to_dict(a.shape),
                "link": a.link,
                "T_link_object": np.asarray(a.T_link_object).tolist(),
                "touch_links": sorted(a.touch_links),
                "support": sorted(a.support),
            }
            for a in snapshot.attachments.values()
        ],
        "outcome": {
            "ok": err is None,
            "plan_s": None if res is None else res.total_time,
            "search_s": None if res is None else res.search_time,
            "simplify_s": None if res is None else res.simplify_time,
            "attempts": None if res is None else res.attempts,
            "planner": None if res is None else res.planner,
            "error": None if err is None else f"{type(err).__name__}: {err}",
        },
    }


class JobRecorder:
    """Writes each job handed to `record` into `directory` (created), numbered on from what is already there, and
    `config` (the service's core config, as a dict) once as config.json: a replay plans with the same settings."""

    def __init__(self, directory: str | Path, config: dict | None = None, max_jobs: int = MAX_JOBS):
        self.directory = Path(directory)
        self.robot = (config or {}).get("robot", {}).get("name")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            if config is not None:
                (self.directory / CONFIG).write_text(json.dumps(config, indent=1))
        except OSError as err:
            raise InvalidInputError(
                f"planning.record_jobs: cannot create {self.directory} ({err}): give a writable directory"
            ) from None
        taken = [int(p.stem.split("-")[1]) for p in self.directory.glob("job-*.npz") if p.stem.split("-")[1].isdigit()]
        self._next = max(taken, default=0) + 1
        self._left = int(max_jobs)
        self.written = self.dropped = 0
        self._queue: queue.Queue = queue.Queue(QUEUE)
        threading.Thread(target=self._write_loop, name="job-recorder", daemon=True).start()

    def record(self, job, snapshot, answer) -> None:
        """Keep `job` (a PlanJob), the world `snapshot` it was planned in and its `answer` (a PlanAnswer)."""
        if self._left <= 0:
            return
        self._left -= 1
        try:
            self._queue.put_nowait((self._next, job, snapshot, answer))
            self._next += 1
        except queue.Full:
            self.dropped += 1

    def flush(self, timeout: float = 10.0) -> None:
        """Wait until every job handed over so far is on disk (tests, and before a replay of a live run)."""
        done = threading.Event()
        self._queue.put((None, done, None, None), timeout=timeout)
        done.wait(timeout)

    def _write_loop(self) -> None:
        while True:
            n, job, snapshot, answer = self._queue.get()
            if n is None:
                job.set()
                continue
            try:
                occ = snapshot.occupancy
                keys = np.zeros((0, 3), np.int32) if occ is None else np.asarray(occ.keys, np.int32)
                np.savez_compressed(
                    self.directory / f"job-{n:06d}.npz",
                    start=np.asarray(job.start, np.float64),
                    q_goal=np.asarray(job.q_goal, np.float64),
                    keys=keys,
                    meta=np.array(json.dumps(_meta(self.robot, job, snapshot, answer))),
                )
                self.written += 1
            except Exception:  # a full disk must not stop the service: say so once per job
                log.exception("could not record planning job %s in %s", n, self.directory)


def recorded_config(directory: str | Path) -> dict | None:
    """The config the jobs in `directory` were planned with (None if it was not kept)."""
    p = Path(directory) / CONFIG
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError) as err:
        raise InvalidInputError(f"{p}: {err}; give the config with -c instead") from None


def load_jobs(directory: str | Path) -> list[RecordedJob]:
    """The jobs recorded in `directory`, in the order they were planned; InvalidInputError naming what is wrong."""
    d = Path(directory)
    if not d.is_dir():
        raise InvalidInputError(f"{d} is not a directory: give the directory planning.record_jobs wrote to")
    files = sorted(d.glob("job-*.npz"))
    if not files:
        raise InvalidInputError(f"no recorded jobs (job-*.npz) in {d}: run the service with planning.record_jobs set")
    return [_load(p) for p in files]


def _load(p: Path) -> RecordedJob:
    try:
        with np.load(p, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            start, q_goal, keys = z["start"], z["q_goal"], np.asarray(z["keys"], np.int64).reshape(-1, 3)
        if meta.get("format") != FORMAT:
            raise ValueError(f"format {meta.get('format')!r}, this version reads {FORMAT}")
        objects = [(o["name"], shape_from_dict(o["shape"]), np.asarray(o["pose"], float)) for o in meta["objects"]]
        attachments = [
            (
                a["name"],
                shape_from_dict(a["shape"]),
                a["link"],
                np.asarray(a["T_link_object"], float),
                tuple(a["touch_links"]),
                tuple(a["support"]),
            )
            for a in meta["attachments"]
        ]
        return RecordedJob(
            p,
            meta.get("robot"),
            meta["purpose"],
            start,
            q_goal,
            float(meta["deadline"]),
            meta["padding"],
            meta["planner"],
            objects,
            attachments,
            keys,
            float(meta["resolution"] or 0.0),
            meta["outcome"],
            None if meta.get("heading") is None else np.asarray(meta["heading"], float),
        )
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as err:  # InvalidInputError too
        raise InvalidInputError(f"{p} is not a recorded planning job this version reads: {err}") from None
