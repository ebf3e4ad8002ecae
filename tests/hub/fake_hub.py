"""An in-memory Hugging Face Hub behind httpx2's MockTransport: huggingface_hub's own client code
runs unchanged, only the HTTP boundary is replaced (``huggingface_hub.set_client_factory``).

As on the real Hub, ``.zip`` and ``.mp4`` files (binary: the Hub takes them through large-file
storage only) are answered ``uploadMode: "lfs"`` by the preupload endpoint; the client then asks the
LFS batch endpoint where to put them, PUTs each object, verifies it and commits it as an
``lfsFile`` (its sha256) instead of inline content. The Xet transfer, which the client prefers when
``hf_xet`` is installed, goes through hf_xet's own network code, outside this HTTP boundary: tests
turn it off (``HF_HUB_DISABLE_XET``) to take the LFS path."""

from __future__ import annotations

import base64
import hashlib
import json
import re

import httpx2

SHA = "0123456789abcdef0123456789abcdef01234567"
HUB = "https://huggingface.co"
#: Endings the fake Hub stores through LFS (binary files: the real Hub refuses them inline).
LFS_SUFFIXES = (".zip", ".mp4")


class FakeHub:
    """Repos as ``{repo_id: {path: bytes}}``; their LFS objects as ``{repo_id: {sha256: bytes}}`` and
    the paths committed through LFS as ``{repo_id: {path}}``; ``fail_with`` makes every request raise that error."""

    def __init__(self) -> None:
        self.repos: dict[str, dict[str, bytes]] = {}
        self.lfs_objects: dict[str, dict[str, bytes]] = {}
        self.lfs_paths: dict[str, set[str]] = {}
        self.commits: list[dict] = []
        self.requests: list[tuple[str, str]] = []
        self.fail_with: Exception | None = None

    def client(self) -> httpx2.Client:
        return httpx2.Client(transport=httpx2.MockTransport(self.handle))

    def handle(self, request: httpx2.Request) -> httpx2.Response:
        if self.fail_with is not None:
            raise self.fail_with
        path = request.url.path
        self.requests.append((request.method, path))
        if request.method == "POST" and path == "/api/repos/create":
            body = json.loads(request.content)
            repo_id = f"{body['organization']}/{body['name']}"
            self.repos.setdefault(repo_id, {})
            return httpx2.Response(200, json={"url": f"https://huggingface.co/{repo_id}", "name": repo_id})
        if path == "/api/validate-yaml":
            return httpx2.Response(200, json={})
        match = re.fullmatch(r"/api/models/([^/]+/[^/]+)/preupload/main", path)
        if match:
            files = json.loads(request.content)["files"]
            modes = [{"path": f["path"], "uploadMode": upload_mode(f["path"]), "shouldIgnore": False} for f in files]
            return httpx2.Response(200, json={"files": modes})
        match = re.fullmatch(r"/([^/]+/[^/]+)\.git/info/lfs/objects/(batch|verify)", path)
        if match:
            return self.lfs(match.group(1), match.group(2), json.loads(request.content))
        match = re.fullmatch(r"/lfs-upload/([^/]+/[^/]+)/([0-9a-f]{64})", path)
        if request.method == "PUT" and match:
            content = request.read()
            if hashlib.sha256(content).hexdigest() != match.group(2):
                return httpx2.Response(400, json={"error": "content does not match its sha256"})
            self.lfs_objects.setdefault(match.group(1), {})[match.group(2)] = content
            return httpx2.Response(200)
        match = re.fullmatch(r"/api/models/([^/]+/[^/]+)/commit/main", path)
        if match:
            repo = self.repos[match.group(1)]
            lines = [json.loads(line) for line in request.content.splitlines() if line.strip()]
            for line in lines:
                if line["key"] == "file":
                    repo[line["value"]["path"]] = base64.b64decode(line["value"]["content"])
                elif line["key"] == "lfsFile":
                    oid = line["value"]["oid"]
                    if oid not in self.lfs_objects.get(match.group(1), {}):
                        return httpx2.Response(
                            422, json={"error": f"LFS object {oid} of {line['value']['path']} not uploaded"}
                        )
                    repo[line["value"]["path"]] = self.lfs_objects[match.group(1)][oid]
                    self.lfs_paths.setdefault(match.group(1), set()).add(line["value"]["path"])
            self.commits.append(lines[0]["value"])
            return httpx2.Response(
                200, json={"commitUrl": f"https://huggingface.co/{match.group(1)}/commit/{SHA}", "commitOid": SHA}
            )
        match = re.fullmatch(r"/api/models/([^/]+/[^/]+)/revision/main", path)
        if match and match.group(1) in self.repos:
            files = self.repos[match.group(1)]
            return httpx2.Response(
                200, json={"id": match.group(1), "sha": SHA, "siblings": [{"rfilename": name} for name in sorted(files)]}
            )
        match = re.fullmatch(r"/api/models/([^/]+/[^/]+)/tree/[^/]+", path)
        if match and match.group(1) in self.repos:
            return httpx2.Response(
                200,
                json=[
                    {"type": "file", "path": name, "size": len(content), "oid": hashlib.sha1(content).hexdigest()}
                    for name, content in sorted(self.repos[match.group(1)].items())
                ],
            )
        match = re.fullmatch(r"/([^/]+/[^/]+)/resolve/[^/]+/(.+)", path)
        if match and match.group(1) in self.repos and match.group(2) in self.repos[match.group(1)]:
            content = self.repos[match.group(1)][match.group(2)]
            headers = {
                "X-Repo-Commit": SHA,
                "ETag": f'"{hashlib.sha1(content).hexdigest()}"',
                "Content-Length": str(len(content)),
            }
            return httpx2.Response(200, headers=headers, content=b"" if request.method == "HEAD" else content)
        return httpx2.Response(
            404, json={"error": f"{request.method} {path} not found"}, headers={"X-Error-Code": "RepoNotFound"}
        )

    def lfs(self, repo_id: str, operation: str, body: dict) -> httpx2.Response:
        """The LFS batch endpoint (``batch``: an upload and a verify action for each object the repo
        does not hold yet, none for one it holds, basic transfer) and the verify one (the object
        stored, of its size)."""
        if repo_id not in self.repos:
            return httpx2.Response(404, json={"error": f"{repo_id} not found"}, headers={"X-Error-Code": "RepoNotFound"})
        stored = self.lfs_objects.setdefault(repo_id, {})
        if operation == "verify":
            if body["oid"] not in stored or len(stored[body["oid"]]) != body["size"]:
                return httpx2.Response(404, json={"error": f"LFS object {body['oid']} not uploaded"})
            return httpx2.Response(200, json={})
        objects = []
        for item in body["objects"]:
            answer = {"oid": item["oid"], "size": item["size"]}
            if item["oid"] not in stored:
                answer["actions"] = {
                    "upload": {"href": f"{HUB}/lfs-upload/{repo_id}/{item['oid']}"},
                    "verify": {"href": f"{HUB}/{repo_id}.git/info/lfs/objects/verify"},
                }
            objects.append(answer)
        return httpx2.Response(200, json={"transfer": "basic", "objects": objects})


def upload_mode(path: str) -> str:
    """``"lfs"`` for the files the Hub stores through large-file storage, ``"regular"`` otherwise."""
    return "lfs" if path.endswith(LFS_SUFFIXES) else "regular"
