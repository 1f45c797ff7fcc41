"""What an update changed in the smoother's Python state, to put back if the update fails."""

from __future__ import annotations

import gtsam


class Undo:
    """What an update changed in the state of the smoother ``s``, to put back if it fails
    (the block factor restores itself): :meth:`run` undoes the steps recorded, last first."""

    def __init__(self, s):
        self.s = s
        self.steps: list = []

    def vars(self, nv0):
        s = self.s
        n_keys = len(s.keys)

        def back():
            for k in s.keys[nv0:]:
                s.var.pop(k, None)
            del s.keys[n_keys:]
            del s.vgroup[n_keys:]
        self.steps.append(back)

    def elements(self, el):
        n = el.n
        self.steps.append(lambda: setattr(el, "n", n))

    def inserted(self, values: gtsam.Values, key: int):
        self.steps.append(lambda: values.erase(key))

    def updated(self, values: gtsam.Values, key: int, old):
        self.steps.append(lambda: values.update(key, old))

    def theta(self, el, e):
        X = el.X[e].copy()

        def back():
            el.X[e] = X
        self.steps.append(back)

    def kind(self, store):
        n = store.n
        self.steps.append(lambda: store.truncate(n))

    def vnative(self):
        s = self.s
        saved = s.vnative.copy()
        self.steps.append(lambda: setattr(s, "vnative", saved))

    def native(self, n):
        s = self.s
        self.steps.append(lambda: s.native.__delitem__(slice(n, None)))

    def run(self):
        for step in reversed(self.steps):
            step()
        self.steps = []
