"""Phase 2: the VAE of the paper's Table I and the latent space it defines (the map D).

Architecture (d = dim θ, d_low = latent size; 10 for d = 25, 5 for d = 77)::

    encoder  d -> ⌊d/2⌋ (ReLU) -> ⌊d/4⌋ (ReLU) -> code of size d_low
    decoder  d_low -> ⌊d/4⌋ (ReLU) -> ⌊d/2⌋ (ReLU) -> d (Sigmoid: a normalized θ in (0, 1)^d)

Two kinds (``kind=``):

* ``"vae"``: the standard reparameterized VAE (the paper authors' code). The encoder's last
  layer gives (μ, log σ²); training samples z = μ + σ·ε. Loss per sample =
  Σ_j (θ̂_j − θ_j)² (summed squared error, the "MSE" of the paper summed over the d entries)
  + β · KL(N(μ, σ²) ‖ N(0, I)), averaged over the batch, β = :data:`BETA_VAE`.
* ``"det"``: the paper's deterministic variant: a sigmoid encoder z = s(W·h) ∈ (0, 1)^d_low and
  a KL on the batch's code statistics: the batch mean m and full covariance Σ define N(m, Σ),
  penalized by KL(N(m, Σ) ‖ N(½, I/12)) (the moments of U(0, 1)^d_low), times β = :data:`BETA_DET`.
  It keeps the codes spread over the unit cube without sampling. The full covariance (its
  −ln det Σ term) keeps the code coordinates decorrelated: with per-coordinate variances only,
  all codes learn the same 1-d signal and the latent box degenerates to a curve plus directions
  the decoder ignores.

Adam, lr 1e-3, batch 64, a fixed number of epochs (default: enough for ~2000 steps, at least
100 epochs); deterministic for a seed (torch's generator is seeded and training runs on one
torch thread).

The latent box
--------------
Phase 3's critic works on a unit box u ∈ [0, 1]^d_low; :class:`LatentSpace` maps it to a code
z = lo + (hi − lo)·u and decodes it. The box [lo, hi] is the bounding box of the encoded training
set (μ for ``vae``, the code for ``det``) widened by ``margin`` (default 10 %) of its width on
each side (and for ``det`` clipped to [0, 1], the sigmoid's range). It is stored with the weights.

Widths and spread
-----------------
Table I's hidden widths (⌊d/2⌋, ⌊d/4⌋) are kept for d ≥ 20; a smaller θ gets two layers of 16
units (:func:`hidden_widths`), where Table I's narrow layers often die and leave a constant
decoder. Training records the decoder's *spread* (:meth:`LatentSpace.spread`): the total
variance of the θ decoded from :data:`SPREAD_CODES` Sobol codes of the latent box over the
training set's total variance (``decoded_variance_ratio`` in the meta). The paper's plain phase 3
refuses a latent space whose codes all decode to one θ (:meth:`LatentSpace.require_spread`).

Few training θ
--------------
n training θ encode to n codes, which span at most n − 1 directions of the d_low-dim code
space; the ``det`` kind's KL needs the batch's code covariance (d_low × d_low) to be of full
rank, which takes at least d_low + 1 codes (:func:`min_training`). With fewer the latent box has
directions no training θ fixes: what the decoder gives there is the untrained network's guess.
Phase 2 warns then (:func:`few_training_note`); more phase-1 trials, or a latent dimension of
at most n − 1, avoid it.

Default kind
------------
``det`` is the default because it reconstructs the stable set better than ``vae``: with β = 1
the ``vae``'s KL pulls the means of a few hundred points together and can collapse the posterior
(reconstruction error = the training set's total variance: every code decodes to the mean θ).
``--vae-kind vae`` remains available.

Compared by ``python -m benchmarks.vae_kind RUN_DIR --kinds det vae --n-check 30`` (reconstruction
error, stable preservation; ``--phase3-evals N`` adds a phase 3); a committed run is in
``results/benchmarks/vae_kind_a1_trot.json``.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from latentune.atomicfile import write_atomic
from latentune.checks import is_whole
from latentune.errors import LatentError

KINDS = ("det", "vae")
"""Autoencoder kinds (see the module docstring)."""
DEFAULT_KIND = "det"
"""The kind :meth:`LatentSpace.train` uses unless told otherwise (see "Default kind")."""
BETA_VAE = 1.0
"""KL weight of the ``vae`` kind (relative to the summed squared reconstruction error)."""
BETA_DET = 0.1
"""Weight of the batch-statistics KL of the ``det`` kind."""
BOX_MARGIN = 0.1
"""Widening of the latent box on each side, as a fraction of its width."""


def default_latent_dim(d: int) -> int:
    """d_low of the paper: 10 for a 25-dim θ, 5 for a 77-dim θ (else max(2, min(10, d // 4)),
    and never more than d − 1: 1 for a 2-dim θ)."""
    if d == 25:
        return 10
    if d == 77:
        return 5
    return min(max(2, min(10, d // 4)), max(1, d - 1))


def _torch():
    import torch

    return torch


SMALL_D = 20
"""Below this θ dimension both hidden layers have :data:`SMALL_WIDTH` units (see
:func:`hidden_widths`)."""
SMALL_WIDTH = 16
"""The hidden width of the networks of a θ of fewer than :data:`SMALL_D` dimensions."""
SPREAD_CODES = 256
"""Sobol codes of the latent box decoded to measure the decoder's spread
(:meth:`LatentSpace.spread`)."""
SPREAD_WARN = 0.01
"""Below this share of the training set's variance, training logs a warning (module docstring,
"Widths and spread")."""


def min_training(d_low: int) -> int:
    """The fewest training θ (d_low + 1) whose codes can span the d_low-dim latent box (and give
    the ``det`` kind's KL a code covariance of full rank): module docstring, "Few training θ"."""
    return int(d_low) + 1


def few_training_note(n: int, d_low: int) -> str | None:
    """One line saying that ``n`` training θ are fewer than :func:`min_training` (``d_low``),
    what it means for phase 3 and what to do; None when they are enough."""
    need = min_training(d_low)
    if n >= need:
        return None
    most = "" if n - 1 == 1 else "at most "
    return (f"the VAE learned from {n} stable θ, fewer than latent dimension + 1 = {need}: they "
            f"fix at most {n - 1} of its {d_low} latent directions, so along the others phase 3's "
            "latent asks decode to the untrained decoder's guesses, not to θ like the stable "
            f"ones; run more phase-1 trials, or train it with a latent dimension of {most}{n - 1} "
            f"(--latent-dim {n - 1}, latent_dim={n - 1})")


def hidden_widths(d: int) -> tuple[int, int]:
    """The two hidden widths (h1, h2) of encoder and decoder for a d-dim θ: Table I's
    (⌊d/2⌋, ⌊d/4⌋) for d ≥ :data:`SMALL_D` (the paper's d = 25 and 77 among them); below it
    (:data:`SMALL_WIDTH`, :data:`SMALL_WIDTH`). With Table I's narrow layers below d = 20 all
    ReLU units of a layer are often off on every input after training, and every code decodes
    to one θ (``python -m benchmarks.vae_widths``)."""
    if d >= SMALL_D:
        return d // 2, d // 4
    return SMALL_WIDTH, SMALL_WIDTH


def _build(d: int, d_low: int, kind: str, widths: tuple[int, int] | None = None):
    """The network for a d-dim θ and a d_low-dim code; ``widths``: the hidden widths (h1, h2)
    (default :func:`hidden_widths`; a latent space saved before them records none and was built
    with ``(max(⌊d/2⌋, 1), max(⌊d/4⌋, 1))``)."""
    torch = _torch()
    nn = torch.nn
    h1, h2 = hidden_widths(d) if widths is None else widths

    class Net(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            out = 2 * d_low if kind == "vae" else d_low
            self.encoder = nn.Sequential(nn.Linear(d, h1), nn.ReLU(), nn.Linear(h1, h2), nn.ReLU(),
                                         nn.Linear(h2, out))
            self.decoder = nn.Sequential(nn.Linear(d_low, h2), nn.ReLU(), nn.Linear(h2, h1),
                                         nn.ReLU(), nn.Linear(h1, d), nn.Sigmoid())

        def encode(self, x):
            e = self.encoder(x)
            if kind == "vae":
                mu, logvar = e[:, :d_low], e[:, d_low:].clamp(-12.0, 8.0)
                return mu, logvar
            return torch.sigmoid(e), None

        def forward(self, x):
            return self.decoder(self.encode(x)[0])

    return Net()


def _loss(net, x, kind: str, beta: float, gen):
    torch = _torch()
    if kind == "vae":
        mu, logvar = net.encode(x)
        eps = torch.randn(mu.shape, generator=gen, dtype=mu.dtype)
        z = mu + torch.exp(0.5 * logvar) * eps
        rec = ((net.decoder(z) - x) ** 2).sum(1).mean()
        kl = (-0.5 * (1 + logvar - mu ** 2 - logvar.exp()).sum(1)).mean()
        return rec + beta * kl, rec
    z, _ = net.encode(x)
    rec = ((net.decoder(z) - x) ** 2).sum(1).mean()
    k = z.shape[1]
    m = z.mean(0)
    zc = z - m
    cov = zc.T @ zc / z.shape[0] + 1e-6 * torch.eye(k, dtype=z.dtype)
    pv = 1.0 / 12.0
    # KL(N(m, Σ) ‖ N(½, I/12)) with the batch's full covariance Σ: its −ln det Σ term keeps the
    # code coordinates decorrelated (see the module docstring)
    kl = 0.5 * (torch.trace(cov) / pv + ((m - 0.5) ** 2).sum() / pv - k
                + k * math.log(pv) - torch.logdet(cov))
    return rec + beta * kl, rec


@dataclass
class TrainLog:
    """Losses of a training run: ``loss``/``rec`` per epoch (mean over batches)."""

    loss: list[float] = field(default_factory=list)
    rec: list[float] = field(default_factory=list)
    wall_s: float = 0.0


class LatentSpace:
    """A trained autoencoder and its latent box: the map D from [0, 1]^d_low to θ ∈ [0, 1]^d.

    Build with :meth:`train` or :meth:`load`. ``space(u)`` / :meth:`decode` map unit-box latent
    points (d_low,) or (n, d_low) to normalized θ; :meth:`encode` maps θ to the code (μ) and
    :meth:`to_unit` a code to the unit box (clipped).
    """

    def __init__(self, net, d: int, d_low: int, kind: str, box: np.ndarray,
                 meta: dict[str, Any] | None = None) -> None:
        self.net = net
        self.d, self.d_low, self.kind = int(d), int(d_low), kind
        self.box = np.asarray(box, dtype=float).reshape(self.d_low, 2)
        self.meta = dict(meta or {})
        self.log = TrainLog()
        self._spread_checked = False          # require_spread passed on this instance

    # ------------------------------------------------------------------ training
    @classmethod
    def train(cls, thetas: np.ndarray, d_low: int | None = None, kind: str = DEFAULT_KIND,
              seed: int = 0, epochs: int | None = None, beta: float | None = None,
              lr: float = 1e-3, batch_size: int = 64, margin: float = BOX_MARGIN,
              meta: dict[str, Any] | None = None,
              hidden: tuple[int, int] | None = None) -> "LatentSpace":
        """Train on normalized θ (n, d) (n ≥ 2) and fix the latent box (see the module docstring).
        ``hidden``: the two hidden widths (default :func:`hidden_widths`), recorded in the meta."""
        torch = _torch()
        X = np.asarray(thetas, dtype=float)
        if X.ndim != 2 or X.shape[0] < 2 or X.shape[1] < 2:
            raise LatentError(f"need at least 2 training points of dimension >= 2, got shape {X.shape}")
        if not np.all(np.isfinite(X)) or X.min() < -1e-9 or X.max() > 1 + 1e-9:
            raise LatentError("training θ must be finite and normalized to [0, 1]")
        if kind not in KINDS:
            raise LatentError(f"unknown VAE kind {kind!r} (choose from {', '.join(KINDS)})")
        n, d = X.shape
        for name, v in (("latent dimension", d_low), ("epochs", epochs)):
            if v is not None and not is_whole(v, 1):
                raise LatentError(f"{name} must be a whole number >= 1, got {v!r}")
        if not is_whole(batch_size, 1) or not is_whole(seed, 0):
            raise LatentError(f"batch_size must be a whole number >= 1 and seed one >= 0, got "
                              f"{batch_size!r} and {seed!r}")
        d_low = default_latent_dim(d) if d_low is None else int(d_low)
        if not 1 <= d_low < d:
            raise LatentError(f"latent dimension must be in [1, {d - 1}], got {d_low}")
        if hidden is not None and (isinstance(hidden, (str, bytes)) or len(hidden) != 2
                                   or not all(is_whole(w, 1) for w in hidden)):
            raise LatentError(f"hidden widths must be >= 1 (two whole numbers), got {hidden!r}")
        widths = hidden_widths(d) if hidden is None else (int(hidden[0]), int(hidden[1]))
        for name, v, ok in (("beta", beta, lambda x: x >= 0), ("lr", lr, lambda x: x > 0)):
            if v is not None and (isinstance(v, bool) or not isinstance(
                    v, (int, float, np.integer, np.floating)) or not math.isfinite(v) or not ok(v)):
                raise LatentError(f"{name} must be a finite number "
                                  f"{'>= 0' if name == 'beta' else '> 0'}, got {v!r}")
        beta = (BETA_VAE if kind == "vae" else BETA_DET) if beta is None else float(beta)
        steps_per_epoch = max(1, math.ceil(n / batch_size))
        if epochs is None:
            epochs = max(100, math.ceil(2000 / steps_per_epoch))
        t0 = time.perf_counter()
        nthreads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            # the initial weights come from torch's global generator: seed it inside a fork, so
            # the caller's random state is restored and the weights depend on ``seed`` alone
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(int(seed))
                net = _build(d, d_low, kind, widths).double()
            gen = torch.Generator().manual_seed(int(seed))
            opt = torch.optim.Adam(net.parameters(), lr=lr)
            Xt = torch.as_tensor(np.clip(X, 0.0, 1.0), dtype=torch.float64)
            log = TrainLog()
            for _ in range(int(epochs)):
                perm = torch.randperm(n, generator=gen)
                tot, totr, k = 0.0, 0.0, 0
                for s in range(0, n, batch_size):
                    xb = Xt[perm[s:s + batch_size]]
                    if xb.shape[0] < 2 and n >= 2:
                        continue
                    loss, rec = _loss(net, xb, kind, beta, gen)
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                    tot += loss.item() * xb.shape[0]
                    totr += rec.item() * xb.shape[0]
                    k += xb.shape[0]
                log.loss.append(tot / max(k, 1))
                log.rec.append(totr / max(k, 1))
            net.eval()
            with torch.no_grad():
                code = net.encode(Xt)[0].numpy()
        finally:
            torch.set_num_threads(nthreads)
        lo, hi = code.min(0), code.max(0)
        w = np.maximum(hi - lo, 1e-3)
        lo, hi = lo - margin * w, hi + margin * w
        if kind == "det":
            lo, hi = np.clip(lo, 0.0, 1.0), np.clip(hi, 0.0, 1.0)
            hi = np.maximum(hi, lo + 1e-3)
        train_var = float(X.var(0).sum())
        m = {"d": d, "d_low": d_low, "kind": kind, "hidden": list(widths),
             "n_train": int(n), "seed": int(seed),
             "epochs": int(epochs), "beta": beta, "lr": lr, "batch_size": batch_size,
             "box_rule": f"bounding box of the encoded training set ± {margin:g}·width"
                         + (" clipped to [0, 1]" if kind == "det" else ""),
             "final_loss": log.loss[-1] if log.loss else None,
             "final_rec": log.rec[-1] if log.rec else None}
        m.update(meta or {})
        out = cls(net, d, d_low, kind, np.stack([lo, hi], 1), m)
        log.wall_s = time.perf_counter() - t0
        out.meta["train_wall_s"] = log.wall_s
        out.meta["train_variance"] = train_var
        out.meta["decoded_variance_ratio"] = (float(out.spread().var(0).sum()) / train_var
                                              if train_var > 0 else None)
        out.log = log
        return out

    # ------------------------------------------------------------------ spread
    def spread(self) -> np.ndarray:
        """The θ (SPREAD_CODES, d) decoded from a scrambled Sobol set (seed 0) of the unit latent
        box: what phase 3 can reach."""
        from scipy.stats import qmc

        return self.decode(qmc.Sobol(self.d_low, scramble=True, seed=0).random(SPREAD_CODES))

    def require_spread(self) -> None:
        """``LatentError`` when every code of the latent box decodes to one θ (the decoded θ of
        :meth:`spread` within 1e-6 of each other in every coordinate): a search of the latent
        box would ask that θ again and again. A latent space that passed is not checked again
        (its network does not change after training or loading), so callers on every path that
        builds a plain critic may call it freely."""
        if self._spread_checked:
            return
        D = self.spread()
        if float(np.max(D.max(0) - D.min(0))) < 1e-6:
            raise LatentError(
                f"the latent space decodes every code to one θ (d={self.d}, d_low={self.d_low}, "
                f"{self.meta.get('n_train', '?')} training θ): train it again (more source "
                "trials, another seed or latent dimension) or use the transfer strategy")
        self._spread_checked = True

    # ------------------------------------------------------------------ maps
    def _as2d(self, a: np.ndarray, k: int, what: str) -> tuple[np.ndarray, bool]:
        """(``a`` as finite floats of shape (n, k), whether it was one point (k,)); LatentError
        for another shape, entries that are not numbers, NaN or inf."""
        try:
            a = np.asarray(a, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise LatentError(f"{what} must be numbers, shape ({k},) or (n, {k})") from None
        single = a.ndim == 1
        if (a.shape[0] if single else a.shape[-1] if a.ndim == 2 else -1) != k:
            raise LatentError(f"{what} must have shape ({k},) or (n, {k}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise LatentError(f"{what} holds NaN or inf")
        return (a.reshape(1, -1) if single else a), single

    def decode_code(self, z: np.ndarray) -> np.ndarray:
        """Codes (d_low,) or (n, d_low) -> normalized θ (d,) or (n, d) (clipped to [0, 1])."""
        torch = _torch()
        z, single = self._as2d(z, self.d_low, "z")
        with torch.no_grad():
            th = self.net.decoder(torch.as_tensor(z, dtype=torch.float64)).numpy()
        th = np.clip(th, 0.0, 1.0)
        return th[0] if single else th

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Unit-box latent points (d_low,) or (n, d_low) (clipped to [0, 1] first) -> codes in
        the latent box, of the same shape."""
        u, single = self._as2d(u, self.d_low, "u")
        z = self.box[:, 0] + (self.box[:, 1] - self.box[:, 0]) * np.clip(u, 0.0, 1.0)
        return z[0] if single else z

    def to_unit(self, z: np.ndarray) -> np.ndarray:
        """Codes (d_low,) or (n, d_low) -> unit-box latent points of the same shape (clipped
        to [0, 1])."""
        z, single = self._as2d(z, self.d_low, "z")
        u = np.clip((z - self.box[:, 0]) / (self.box[:, 1] - self.box[:, 0]), 0.0, 1.0)
        return u[0] if single else u

    def decode(self, u: np.ndarray) -> np.ndarray:
        """The map D: unit-box latent points (d_low,) or (n, d_low) (clipped to [0, 1]) ->
        normalized θ (d,) or (n, d)."""
        u, single = self._as2d(u, self.d_low, "u")
        th = self.decode_code(self.from_unit(u))
        return th[0] if single else th

    __call__ = decode

    def encode(self, theta: np.ndarray) -> np.ndarray:
        """Normalized θ (d,) or (n, d) -> codes (d_low,) or (n, d_low) (μ for ``vae``; not
        clipped to the latent box: :meth:`to_unit` clips)."""
        torch = _torch()
        x, single = self._as2d(theta, self.d, "theta")
        with torch.no_grad():
            z = self.net.encode(torch.as_tensor(x, dtype=torch.float64))[0].numpy()
        return z[0] if single else z

    def reconstruct(self, theta: np.ndarray) -> np.ndarray:
        """encode -> decode (the code itself, not clipped to the box)."""
        return self.decode_code(self.encode(theta))

    def fingerprint(self) -> str:
        """A short hash (12 hex digits) of the latent box and the network's weights: equal for
        the same latent space, saved and loaded again, wherever its files are."""
        h = hashlib.sha1(np.asarray(self.box, dtype=float).tobytes())
        for v in self.net.state_dict().values():
            h.update(v.detach().cpu().numpy().tobytes())
        return h.hexdigest()[:12]

    # ------------------------------------------------------------------ files
    def save(self, path_prefix: str | Path) -> tuple[str, str]:
        """Write ``PREFIX.pt`` (state dict) and ``PREFIX.json`` (meta); return both paths.
        Each file is written to a temporary name and renamed, so a failed write (a full disk:
        an :class:`OSError` with its errno) leaves any earlier files as they were."""
        import io

        torch = _torch()
        p = Path(path_prefix)
        pt, js = p.with_suffix(".pt"), p.with_suffix(".json")
        buf = io.BytesIO()
        torch.save(self.net.state_dict(), buf)
        meta = dict(self.meta)
        meta.update({"format": "latentune-latent-space", "version": 1, "d": self.d,
                     "d_low": self.d_low, "kind": self.kind, "box": self.box.tolist()})
        for path, data in ((pt, buf.getvalue()), (js, json.dumps(meta, indent=1).encode())):
            write_atomic(path, data)
        return str(pt), str(js)

    @classmethod
    def load(cls, path_prefix: str | Path) -> "LatentSpace":
        """Read a latent space written by :meth:`save` (``LatentError`` if missing or corrupt)."""
        torch = _torch()
        if not isinstance(path_prefix, (str, os.PathLike)):
            raise LatentError(f"a latent space's path is a str or Path, got {path_prefix!r:.40}")
        p = Path(path_prefix)
        pt, js = p.with_suffix(".pt"), p.with_suffix(".json")
        if not pt.is_file() or not js.is_file():
            raise LatentError(f"no latent space at {p} (expected {pt.name} and {js.name})")
        try:
            meta = json.loads(js.read_text())
            if meta.get("format") != "latentune-latent-space":
                raise ValueError("not a latentune latent space")
            d, d_low, kind = int(meta["d"]), int(meta["d_low"]), str(meta["kind"])
            if kind not in KINDS:
                raise ValueError(f"unknown kind {kind!r}")
            box = np.asarray(meta["box"], dtype=float).reshape(d_low, 2)
            # saved before "hidden" was recorded: the widths of that time
            widths = tuple(int(w) for w in meta["hidden"]) if "hidden" in meta else \
                (max(d // 2, 1), max(d // 4, 1))
            net = _build(d, d_low, kind, widths).double()  # type: ignore[arg-type]
            net.load_state_dict(torch.load(pt, map_location="cpu", weights_only=True))
            net.eval()
        except LatentError:
            raise
        except Exception as exc:  # noqa: BLE001 - any parse/shape error means a corrupt file
            raise LatentError(f"corrupt latent space {p}: {' '.join(str(exc).split())[:200]}") from None
        return cls(net, d, d_low, kind, box, meta)

    def __getstate__(self) -> dict[str, Any]:
        """Picklable (the network's class is built at run time): its hidden widths and weights
        stand for it (an Optuna study with a ``LatentSampler`` saved by ``joblib.dump``)."""
        state = dict(self.__dict__)
        net = state.pop("net")
        state["net_weights"] = ((net.encoder[0].out_features, net.encoder[2].out_features),
                                {k: v.detach().cpu().clone() for k, v in
                                 net.state_dict().items()})
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        widths, weights = state.pop("net_weights")
        net = _build(state["d"], state["d_low"], state["kind"], tuple(widths)).double()
        net.load_state_dict(weights)
        net.eval()
        self.__dict__.update(state, net=net)

    def __repr__(self) -> str:
        return f"LatentSpace(d={self.d}, d_low={self.d_low}, kind={self.kind!r})"
