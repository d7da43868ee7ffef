"""One bake on the service, run on a background thread so Blender's UI never waits.

The thread uploads the mesh assets, creates the scene, submits the bake and polls
``GET /v1/bakes/{id}`` every ``POLL_SECONDS`` until the bake is final; the UI reads
:meth:`BakeJob.snapshot` from a timer. No bpy here: the scene document is exported on the
main thread before the job starts.

Invariants: every outcome ends in ``state`` ``succeeded``, ``failed`` or ``cancelled`` with a
``message``; a 422 from scene validation also fills ``object_errors`` with one
``(object id, message)`` per object the message names (``block "a"``, ``clutter "b"``).
"""

import copy
import re
import threading
import time

from .service import ServiceError

POLL_SECONDS = 0.5
FINAL = ("succeeded", "failed", "cancelled")
_NAMED = re.compile(r'\b(block|clutter|dynamic) "([^"]+)"')


def objects_named(message):
    """``(kind, id)`` of every object a service message names, in order, without repeats."""
    seen = []
    for match in _NAMED.finditer(message):
        if match.groups() not in seen:
            seen.append(match.groups())
    return seen


class BakeJob:
    """A bake of ``scene`` (a scene document whose mesh clutter has ``mesh: None``) with the
    GLB bytes of those meshes in ``meshes`` (clutter id -> bytes), settings overrides
    ``settings``, on ``service``."""

    def __init__(self, service, scene, meshes, settings):
        self.service = service
        self.scene = copy.deepcopy(scene)
        self.meshes = meshes
        self.settings = settings
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self._status = {"state": "starting", "stage": "uploading", "progress": 0.0,
                        "message": "", "bake_id": None, "cached": False,
                        "object_errors": []}
        self._thread = threading.Thread(target=self._run, name="lightfarm bake", daemon=True)

    def start(self):
        self._thread.start()
        return self

    def snapshot(self):
        """A copy of the current status: state, stage, progress (0-1), message, bake_id,
        cached, object_errors."""
        with self._lock:
            return copy.deepcopy(self._status)

    def done(self):
        return self.snapshot()["state"] in FINAL

    def join(self, timeout=None):
        self._thread.join(timeout)

    def cancel(self):
        """Asks the service to cancel (the thread then sees ``cancelled``)."""
        self._cancel.set()
        bake_id = self.snapshot()["bake_id"]
        if bake_id:
            try:
                self.service.cancel_bake(bake_id)
            except ServiceError as error:
                self._set(message="cancel: " + error.message)

    def _set(self, **fields):
        with self._lock:
            self._status.update(fields)

    def _run(self):
        try:
            self._bake()
        except ServiceError as error:
            errors = []
            if error.status == 422:
                errors = [(name, error.message) for _, name in objects_named(error.message)]
            self._set(state="failed", message=error.message, object_errors=errors)
        except Exception as error:  # noqa: BLE001 - the UI shows it instead of a traceback
            self._set(state="failed", message=f"unexpected error: {error}")

    def _bake(self):
        for item in self.scene.get("clutter", []):
            if "mesh" in item and item["mesh"] is None:
                self._set(stage=f"uploading {item['id']}")
                item["mesh"] = self.service.upload_asset(self.meshes[item["id"]])
        self._set(stage="creating scene")
        scene_id = self.service.create_scene(self.scene)
        if self._cancel.is_set():
            self._set(state="cancelled", message="cancelled before submission")
            return
        status, cached = self.service.submit_bake(scene_id, self.settings)
        self._set(bake_id=status["id"], cached=cached)
        while True:
            state = status["state"]
            self._set(state=state, stage=status.get("stage") or state,
                      progress=float(status.get("progress") or 0.0))
            if state in FINAL:
                message = {"succeeded": "reused the earlier identical bake" if cached
                           else "baked", "cancelled": "cancelled"}.get(state)
                self._set(message=message or status.get("error") or "bake failed",
                          progress=1.0 if state == "succeeded" else status.get("progress", 0.0))
                return
            time.sleep(POLL_SECONDS)
            status = self.service.bake_status(status["id"])
