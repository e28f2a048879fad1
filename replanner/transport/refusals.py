"""What Zenoh's access control refused in this process, logged and counted.

Zenoh drops a denied message before any callback of ours, and says so only in its own log (TRACE, on stdout). So
with access control on, a process reads its own stdout through a pipe: Zenoh's access-control lines are parsed here,
every other line goes on to the real stdout unchanged."""

from __future__ import annotations

import json
import logging
import os
import re
import sys
import threading
import time
from collections import Counter

import zenoh

log = logging.getLogger(__name__)

MODULE = "zenoh::net::routing::interceptor::access_control"
# After "caching permissions for K", Zenoh states a verdict per action, in this order, once per rule subject tried:
# computed, not messages refused. A session in no rule has no subject, and its block has no lines at all.
CACHED_ACTIONS = (
    "Query",
    "Reply",
    "Put",
    "Delete",
    "Declare/Undeclare Subscriber",
    "Declare/Undeclare Queryable",
    "Declare/Undeclare Liveliness Token",
    "Liveliness Query",
    "Declare Liveliness Subscriber",
)
ACTION_AT = {action: i for i, action in enumerate(CACHED_ACTIONS)}
MAX_KINDS = 256  # anyone may try anything: the table of what was refused stays bounded
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_THREAD = re.compile(r"ThreadId\((\d+)\)")
_CACHING = re.compile(r"ACL \((?P<flow>ingress|egress)\): caching permissions for `(?P<key>[^`]*)`")
_VERDICT = re.compile(
    r"(?P<cached>Using cached result: )?(?P<zid>[0-9a-f]+)(?: on (?P<via>\S+))? is (?P<un>un)?authorized to "
    r"(?P<what>.+?) \((?P<flow>ingress|egress)\) on (?P<key>\S+)\s*$"
)
_NO_ROLE = re.compile(r"(?P<zid>[0-9a-f]+) did not match any configured ACL subject")
_NAME = re.compile(r"CertCommonName\(([^)]*)\)")


class Refusals:
    """Counts of refused messages by (who, what, flow, key), and of sessions that matched no rule.

    Args:
        summary_every: [s] a summary line at most this often while refusals go on (the first of each kind is
            logged at once).
        clock: for the summaries only.
    """

    def __init__(self, summary_every: float = 10.0, clock=time.monotonic):
        self.counts: Counter = Counter()
        self.no_role: Counter = Counter()  # session id -> times Zenoh found it in no rule
        self.total = 0
        self.summary_every, self.clock = summary_every, clock
        self._blocks: dict[str, list] = {}  # thread -> [flow, key, zid, index of the last action] of a caching block
        self._names: dict[str, str] = {}  # session id -> certificate name, once seen
        self._summarized: tuple[float, int] | None = None  # (when, total) of the last summary
        self._lock = threading.Lock()

    def feed(self, line: str) -> bool:
        """One line of Zenoh's log; True if it was an access-control line (consumed here)."""
        line = _ANSI.sub("", line)
        if MODULE not in line:
            return False
        body = line.split(MODULE + ":", 1)[-1].strip()
        thread = m.group(1) if (m := _THREAD.search(line)) else ""
        if (m := _CACHING.search(body)) is not None:
            self._blocks[thread] = [m["flow"], m["key"], None, -1]
            return True
        if (m := _NO_ROLE.search(body)) is not None:
            with self._lock:
                first = m["zid"] not in self.no_role
                if not first or len(self.no_role) < MAX_KINDS:
                    self.no_role[m["zid"]] += 1
            if first:
                log.warning("refused: session %s matches no access rule (every message of it is denied)", m["zid"])
            return True
        m = _VERDICT.search(body)
        if m is None:
            return True
        if m["via"] and (name := _NAME.search(m["via"])) and len(self._names) < MAX_KINDS:
            self._names[m["zid"]] = name.group(1)
        if not m["cached"] and self._in_block(thread, m):
            return True
        self._blocks.pop(thread, None)
        if m["un"]:
            self._count(self._names.get(m["zid"], m["zid"][:8]), m["what"], m["flow"], m["key"])
        return True

    def _in_block(self, thread: str, m: re.Match) -> bool:
        """Whether a verdict line is the next of its thread's caching block: same flow, key and session, and the
        same action (the next rule subject) or the next one in order. Anything else ends the block."""
        block = self._blocks.get(thread)
        at = ACTION_AT.get(m["what"])
        if block is None or at is None:
            return False
        flow, key, zid, last = block
        if m["flow"] != flow or m["key"] != key or zid not in (None, m["zid"]) or at not in (last, last + 1):
            return False
        block[2:] = [m["zid"], at]
        return True

    def _count(self, who: str, what: str, flow: str, key: str) -> None:
        kind = (who, what, flow, key)
        with self._lock:
            first = kind not in self.counts
            if first and len(self.counts) >= MAX_KINDS:
                kind = ("(other)", "(other)", flow, "(other)")
            self.counts[kind] += 1
            self.total += 1
        if first:
            log.warning("refused: %s from %s on %s (%s; Zenoh access control)", what, who, key, flow)
        now = self.clock()
        if self._summarized is None:  # the first refusal was logged above: summaries count from it
            self._summarized = (now, self.total)
        then, seen = self._summarized
        if now - then >= self.summary_every and self.total > seen:
            log.warning("refused %d messages so far (%d in the last %.0f s)", self.total, self.total - seen, now - then)
            self._summarized = (now, self.total)

    def table(self) -> dict[str, int]:
        """{"<who>: <what> (<flow>) on <key>": count}: the status's `access_refused`."""
        with self._lock:
            return {f"{w}: {a} ({f}) on {k}": n for (w, a, f, k), n in sorted(self.counts.items())}

    @classmethod
    def capture(cls, **kw) -> Refusals:
        """Read this process's stdout through a pipe and turn Zenoh's access-control log on; call once, before the
        session opens. A user's own RUST_LOG is kept (and then its lines are shown too)."""
        refusals = cls(**kw)
        user = os.environ.get("RUST_LOG")
        os.environ["RUST_LOG"] = f"{user},{MODULE}=trace" if user else f"error,{MODULE}=trace"
        out = os.dup(1)
        r, w = os.pipe()
        try:
            import fcntl

            fcntl.fcntl(w, 1031, 1 << 20)  # F_SETPIPE_SZ: room for bursts
        except OSError:
            pass
        os.set_blocking(w, False)  # a slow reader drops Zenoh's log lines, never stalls Zenoh's threads
        os.dup2(w, 1)
        os.close(w)
        sys.stdout.flush()
        sys.stdout = open(out, "w", buffering=1, closefd=False)  # noqa: SIM115 (the process's stdout, for good)
        threading.Thread(target=refusals.relay, args=(r, out, user is not None), name="refusals", daemon=True).start()
        zenoh.init_log_from_env_or("error")
        return refusals

    def relay(self, r: int, out: int, show: bool) -> None:
        """Read the captured stdout from `r`: note the refusals, pass the rest on to `out` (`show`: refusals too)."""
        with os.fdopen(r, "rb") as pipe:
            for raw in pipe:
                try:
                    if not self.feed(raw.decode("utf-8", "replace")) or show:
                        os.write(out, raw)
                except Exception:
                    log.exception("reading Zenoh's log failed")


def access_control_on(conf: zenoh.Config) -> bool:
    try:
        return bool(json.loads(conf.get_json("access_control/enabled")))
    except Exception:
        return False
