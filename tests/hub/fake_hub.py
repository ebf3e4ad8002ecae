"""An in-memory Hugging Face Hub behind httpx2's MockTransport: huggingface_hub's own client code
runs unchanged, only the HTTP boundary is replaced (``huggingface_hub.set_client_factory``)."""

from __future__ import annotations

import base64
import hashlib
import json
import re

import httpx2

SHA = "0123456789abcdef0123456789abcdef01234567"


class FakeHub:
    """Repos as ``{repo_id: {path: bytes}}``; ``fail_with`` makes every request raise that error."""

    def __init__(self) -> None:
        self.repos: dict[str, dict[str, bytes]] = {}
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
            return httpx2.Response(
                200, json={"files": [{"path": f["path"], "uploadMode": "regular", "shouldIgnore": False} for f in files]}
            )
        match = re.fullmatch(r"/api/models/([^/]+/[^/]+)/commit/main", path)
        if match:
            repo = self.repos[match.group(1)]
            lines = [json.loads(line) for line in request.content.splitlines() if line.strip()]
            for line in lines:
                if line["key"] == "file":
                    repo[line["value"]["path"]] = base64.b64decode(line["value"]["content"])
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
