"""The lightfarm service over HTTP (urllib only; no bpy here, so it runs in a thread).

Owns the requests the add-on makes: ``POST /v1/assets``, ``POST /v1/scenes``,
``POST /v1/bakes``, ``GET``/``DELETE /v1/bakes/{id}`` and ``POST /v1/bakes/{id}/evaluate``.
Bodies are JSON (UTF-8) except asset uploads (GLB bytes). Answers are asked for gzip-compressed
(``Accept-Encoding: gzip``; Python 3.11's standard library has no zstd): the service compresses
the evaluate document, a 1,000-block level's 80.6 MB in 15.7 MB, and leaves the rest as they are.

Invariant: every failure is a :class:`ServiceError` with a message a level artist can act
on (the service down, a wrong token, the service's own error text); nothing else escapes.
"""

import gzip
import json
import urllib.error
import urllib.request

# Seconds to wait for an answer; evaluation of a large level takes a few seconds.
TIMEOUT_SECONDS = 60.0


class ServiceError(Exception):
    """A request that failed. ``status`` is the HTTP status (None when the service was not
    reached); ``message`` the service's error text or why it was not reached."""

    def __init__(self, message, status=None):
        super().__init__(message)
        self.message = message
        self.status = status


class Service:
    """One service (base URL such as ``http://127.0.0.1:8080``) and team token (may be empty
    for an open local service)."""

    def __init__(self, url, token=""):
        self.url = url.rstrip("/")
        self.token = token.strip()
        # The last answer's bytes on the wire and its Content-Encoding (None: uncompressed).
        self.last_wire_bytes = 0
        self.last_encoding = None

    def _request(self, method, path, body=None, content_type="application/json"):
        """Sends one request; returns (status, parsed JSON or None, response headers)."""
        headers = {"Accept": "application/json", "Accept-Encoding": "gzip"}
        if self.token:
            headers["Authorization"] = "Bearer " + self.token
        data = None
        if body is not None:
            data = body if isinstance(body, bytes) else json.dumps(body).encode("utf-8")
            headers["Content-Type"] = content_type
        request = urllib.request.Request(self.url + path, data=data, headers=headers,
                                         method=method)
        try:
            with urllib.request.urlopen(request, timeout=TIMEOUT_SECONDS) as response:
                text = self._body(response)
                return response.status, (json.loads(text) if text else None), response.headers
        except urllib.error.HTTPError as error:
            raw = self._body(error)
            try:
                message = json.loads(raw)["error"]
            except (ValueError, KeyError, TypeError):
                message = raw.decode("utf-8", "replace").strip() or error.reason
            if error.code == 401:
                message = "the service refused the team token (add-on preferences): " + message
            raise ServiceError(message, error.code) from None
        except (urllib.error.URLError, OSError, ValueError) as error:
            reason = getattr(error, "reason", error)
            raise ServiceError(
                f"the lightfarm service at {self.url} is not reachable ({reason}); "
                "start it with `lightfarm serve` or fix the URL in the add-on preferences"
            ) from None

    def _body(self, response):
        """The answer's bytes, decompressed when the service sent them gzip-compressed."""
        raw = response.read()
        self.last_wire_bytes = len(raw)
        self.last_encoding = response.headers.get("Content-Encoding")
        if self.last_encoding != "gzip":
            return raw
        try:
            return gzip.decompress(raw)
        except (OSError, EOFError) as error:
            raise ServiceError(
                f"the answer from {self.url} was damaged on the way ({error}); try again"
            ) from None

    def upload_asset(self, glb):
        """``POST /v1/assets`` with GLB bytes; returns the asset's hash."""
        _, answer, _ = self._request("POST", "/v1/assets", glb, "model/gltf-binary")
        return answer["hash"]

    def create_scene(self, scene):
        """``POST /v1/scenes``; returns the scene id. A 422 names the object at fault."""
        _, answer, _ = self._request("POST", "/v1/scenes", scene)
        return answer["id"]

    def submit_bake(self, scene_id, settings=None):
        """``POST /v1/bakes``; returns (status dict, cached): cached when the same bake
        finished before (200)."""
        code, answer, _ = self._request("POST", "/v1/bakes",
                                     {"scene": scene_id, "settings": settings or {}})
        return answer, code == 200

    def bake_status(self, bake_id):
        """``GET /v1/bakes/{id}``."""
        return self._request("GET", "/v1/bakes/" + bake_id)[1]

    def cancel_bake(self, bake_id):
        """``DELETE /v1/bakes/{id}``."""
        return self._request("DELETE", "/v1/bakes/" + bake_id)[1]

    def evaluate(self, bake_id, lights, method=None, bounces=None):
        """``POST /v1/bakes/{id}/evaluate``: returns (the RESULT.json document for LIGHTS.json,
        the bounces the service summed or None). ``bounces``: a whole number >= 1 or "all"
        (None: the service's default, all)."""
        query = "&".join(f"{key}={value}" for key, value in
                         (("method", method), ("bounces", bounces)) if value)
        path = f"/v1/bakes/{bake_id}/evaluate" + ("?" + query if query else "")
        _, result, headers = self._request("POST", path, lights)
        summed = headers.get("lightfarm-bounces")
        return result, int(summed) if summed and summed.isdigit() else None
