"""One ``icefarm run`` as a separate process: its progress read from its stdout lines, its
stderr kept for the error, and a cancel that ends it and everything it started.

Standard library only (no ``bpy``): Blender polls it from the operator.
"""

import os
import queue
import re
import signal
import subprocess
import threading

from .command import GrowError

# A job's steps (icefarm.job.pipeline) and their rough share of its time, from an icefarm run
# on a 1 m cube and a 0.3 m bunny: the surface (meshing the ice) and a render dominate.
STEP_WEIGHTS = {"prepare": 1, "proxy": 1, "water": 2, "drips": 1, "trajectories": 1, "surface": 8, "measure": 2}
RENDER_STEP_WEIGHTS = {"render": 10, "usd": 1}
STOP_WAIT_S = 3.0  # how long a cancelled job has to end on SIGTERM before SIGKILL


class Progress:
    """A job's progress from its stdout lines (icefarm's ``LINES`` progress mode).

    ``feed`` each line: ``NAME ...`` starts a step, ``NAME done in S s`` ends it,
    ``  NAME: text`` says what the current step is doing; the summary's ``  ice: ...`` line
    is kept. ``fraction`` is the weighted share of the steps done, below 1 until `finish`.
    """

    _END = re.compile(r"^(\S+) (done in|failed after) [0-9.]+ s$")

    def __init__(self, render=False):
        self.weights = dict(STEP_WEIGHTS, **(RENDER_STEP_WEIGHTS if render else {}))
        self.done = []
        self.step = self.detail = self.summary = ""
        self.finished = False

    def feed(self, line):
        text = line.rstrip("\r\n")
        if text.startswith("  "):
            name, _, detail = text.strip().partition(": ")
            if name == "ice" and detail:
                self.summary = text.strip()
            elif name == self.step and detail:
                self.detail = detail
            return
        end = self._END.match(text)
        if end:
            self.done.append(end.group(1))
            self.step = self.detail = ""
        elif text.endswith(" ...") and " " not in text[:-4]:
            self.step, self.detail = text[:-4], ""

    def finish(self):
        self.finished = True

    @property
    def fraction(self):
        if self.finished:
            return 1.0
        total = sum(self.weights.values())
        done = sum(self.weights.get(name, 0) for name in set(self.done))
        return min(done / total, 0.99)

    @property
    def text(self):
        if self.finished:
            return "done"
        if not self.step:
            return f"{self.done[-1]} done" if self.done else "starting"
        return ": ".join(part for part in (self.step, self.detail) if part)


class IcefarmProcess:
    """One running ``icefarm run``: its stdout and stderr read by two threads so that
    polling never blocks Blender, and a `cancel` that ends it and its children."""

    def __init__(self, command, render=False):
        self.command = list(command)
        self.progress = Progress(render)
        self._lines = queue.Queue()
        self._stderr = []
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "PYTHONPATH")}  # Blender's
        options = {"start_new_session": True} if os.name == "posix" else {
            "creationflags": getattr(subprocess, "CREATE_NEW_PROCESS_GROUP", 0)}
        try:
            self.process = subprocess.Popen(self.command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                            stderr=subprocess.PIPE, text=True, encoding="utf-8",
                                            errors="replace", bufsize=1, env=env, **options)
        except OSError as exc:
            raise GrowError(f"cannot run icefarm ({self.command[0]}): {exc.strerror or exc}; set its path in "
                            "the icefarm add-on's preferences or the ICEFARM environment variable") from None
        self._threads = [threading.Thread(target=self._read, args=(self.process.stdout, self._lines.put), daemon=True),
                         threading.Thread(target=self._read, args=(self.process.stderr, self._stderr.append),
                                          daemon=True)]
        for thread in self._threads:
            thread.start()

    @property
    def pid(self):
        return self.process.pid

    @staticmethod
    def _read(stream, put):
        for line in stream:
            put(line)
        stream.close()

    def poll(self):
        """Read what the job wrote since; None while it runs, else its exit status."""
        returncode = self.process.poll()
        if returncode is not None:
            for thread in self._threads:  # the pipes' last lines
                thread.join(timeout=5.0)
        while True:
            try:
                self.progress.feed(self._lines.get_nowait())
            except queue.Empty:
                break
        if returncode == 0:
            self.progress.finish()
        return returncode

    @property
    def stderr(self):
        return "".join(self._stderr)

    def warnings(self):
        return [line.strip() for line in self._stderr if line.startswith("warning:")]

    def cancel(self):
        """End the job and everything it started (its process group), SIGTERM first."""
        if self.process.poll() is None:  # (a finished job's group id may belong to another by now)
            self._signal(signal.SIGTERM)
            try:
                self.process.wait(STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                pass
            self._signal(getattr(signal, "SIGKILL", signal.SIGTERM))  # it, or children left in its group
            self.process.wait()
        for thread in self._threads:
            thread.join(timeout=5.0)

    def _signal(self, signum):
        if os.name == "posix":
            try:
                os.killpg(self.process.pid, signum)
            except (ProcessLookupError, PermissionError):
                pass
        elif self.process.poll() is None:
            subprocess.run(["taskkill", "/F", "/T", "/PID", str(self.process.pid)], capture_output=True)
