"""Phase 2: the latent space (a VAE, :mod:`latentune.latent.vae`) trained on the θ of phase 1
whose trial did not fail (:func:`~latentune.pipeline.phases.training_set`)."""
from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from numbers import Integral
from typing import Any, Iterator

from latentune.checks import is_whole
from latentune.constants import Phase
from latentune.errors import LatentError, UsageError
from latentune.pipeline.manifest import Manifest
from latentune.pipeline.phases import training_set
from latentune.pipeline.rundir import RunDir

logger = logging.getLogger(__name__)


def stale_latent(store: Any, vae: dict[str, Any]) -> bool:
    """True when ``store`` holds a latent space whose record ``vae`` (the manifest's) says it
    was trained on fewer θ than phase 1 now holds whose trial did not fail (phase 1 grew
    since)."""
    n = vae.get("n_train")
    return store.artifact("vae") is not None and n is not None and \
        int(n) < len(training_set(store, Phase.PHASE1))


@contextmanager
def wall_kept(manifest: Manifest, key: str) -> Iterator[None]:
    """Outside a rollback (:meth:`~latentune.pipeline.rundir.RunDir.as_before_on_error`),
    inside the write lock: a Ctrl-C (KeyboardInterrupt) in the block adds the block's wall
    time [s] to ``wall[key]`` after the rollback removed the record of it, so that the run
    still counts the time spent (a refusal adds nothing: the directory is left as it was)."""
    t = time.perf_counter()
    try:
        yield
    except KeyboardInterrupt:
        manifest.add_wall(key, time.perf_counter() - t)
        raise


def train_latent(run: RunDir, manifest: Manifest, seed: int, latent_dim: int | None = None,
                 kind: str | None = None, epochs: int | None = None, retrain: bool = False
                 ) -> tuple[Any, str | None]:
    """(the run's LatentSpace, a one-line message or None when it was trained before).

    Trains it with ``seed`` and saves it as ``DIR/vae.pt`` / ``DIR/vae.json``; a trained one is
    returned as it is unless ``retrain`` (UsageError for another ``latent_dim``, ``kind`` or
    ``epochs``: :func:`trained_differs`; LatentError for a latent_dim that is not a whole number
    >= 1, checked first); retraining after phase 3 used it is refused (it
    would invalidate the stored phase-3 rows). Logs a warning when the latent space decodes to
    little of the training θ's variance (``SPREAD_WARN``) and when the stable θ are fewer than
    the latent dimension + 1 (:func:`latentune.latent.vae.few_training_note`). Call with the
    run's write lock held."""
    from latentune.latent.vae import (DEFAULT_KIND, SPREAD_WARN, LatentSpace,
                                      few_training_note)

    if epochs is not None and (isinstance(epochs, bool) or not isinstance(epochs, Integral)
                               or epochs < 1):
        raise UsageError(f"epochs must be a whole number >= 1 (or None: the default), got "
                         f"{epochs!r}")
    if latent_dim is not None and not is_whole(latent_dim, 1):
        raise LatentError(f"latent dimension must be a whole number >= 1, got {latent_dim!r}")
    st = run.store
    if st.artifact("vae") is not None:
        if not retrain:
            latent = LatentSpace.load(st.artifact("vae"))
            diff = trained_differs({"d_low": latent.d_low, "kind": latent.kind,
                                    "epochs": latent.meta.get("epochs")}, latent_dim, kind, epochs)
            if diff is not None:
                raise UsageError(f"{run.dir}: its latent space is trained already with "
                                 f"{diff[0]} = {diff[2]!r}, not {diff[1]!r}: leave {diff[0]} "
                                 "out to use it, or retrain it (retrain=True)")
            vae = manifest.config().get("vae") or {}
            if stale_latent(st, vae):
                logger.warning("%s: the latent space was trained on %d θ that did not fail; "
                               "phase 1 holds %d now: it is kept as it is (retrain=True, or "
                               "train-vae without --resume, trains it on all)", run.dir,
                               int(vae["n_train"]), len(training_set(st, Phase.PHASE1)))
            return latent, None
        if st.count(Phase.PHASE3) > 0 and manifest.config().get("phase3_vae_source") == "self":
            raise LatentError(f"{run.dir}: phase 3 already used the VAE; retraining it "
                              "would invalidate the stored phase-3 rows (use another dir)")
    X = training_set(st, Phase.PHASE1)
    if len(X) < 2:
        raise LatentError(f"{run.dir}: phase 1 has {len(X)} θ whose trial did not fail; "
                          "the latent space needs at least 2 (run more phase-1 evaluations)")
    cfg = manifest.config()
    meta = {"source_run": str(run.dir.resolve()), "n_phase1": st.count(Phase.PHASE1),
            "system": cfg.get("system"), "space_names": cfg.get("space", {}).get("names")}
    if "task" in cfg:
        meta.update({k: cfg["task"][k] for k in ("robot", "gait", "actor", "terrain")})
    with manifest.timing("vae"):
        latent = LatentSpace.train(X, d_low=latent_dim, kind=kind or DEFAULT_KIND, seed=seed,
                                   epochs=epochs, meta=meta)
        latent.save(run.dir / "vae")
    st.add_artifact("vae", run.dir / "vae")
    manifest.update(vae={"kind": latent.kind, "d_low": latent.d_low, "n_train": len(X),
                         "epochs": latent.meta.get("epochs"),
                         "seed": seed, "beta": latent.meta.get("beta"),
                         "box": latent.box.tolist(), "box_rule": latent.meta.get("box_rule"),
                         "decoded_variance_ratio": latent.meta.get("decoded_variance_ratio")})
    manifest.record_seed(seed)
    ratio = latent.meta.get("decoded_variance_ratio")
    if ratio is not None and ratio < SPREAD_WARN:
        logger.warning("%s: the latent box decodes to %.2g of the training θ's variance: the "
                       "paper's plain phase 3 can reach little beyond one θ", run.dir, ratio)
    few = few_training_note(len(X), latent.d_low)
    if few is not None:
        logger.warning("%s: %s", run.dir, few)
    spread = "" if ratio is None else f"; decoded spread {ratio:.3f} of the training variance"
    rec = latent.meta.get("final_rec")
    return latent, (f"VAE ({latent.kind}, d_low {latent.d_low}) trained on {len(X)} θ in "
                    f"{latent.meta.get('train_wall_s', 0):.1f} s; final reconstruction error "
                    f"{float('nan') if rec is None else rec:.4f}{spread}")


def trained_differs(stored: dict[str, Any], latent_dim: int | None = None,
                    kind: str | None = None, epochs: int | None = None
                    ) -> tuple[str, Any, Any] | None:
    """``(name, given, stored)`` of the first of ``latent_dim``, ``kind`` and ``epochs`` (None:
    not given) that differs from the trained latent space's record ``stored`` (``d_low``,
    ``kind``, ``epochs``; a key it lacks is not compared); None when every one given agrees.
    A trained latent space is kept as it is, so an option that differs would be ignored."""
    for name, key, given in (("latent_dim", "d_low", latent_dim), ("kind", "kind", kind),
                             ("epochs", "epochs", epochs)):
        if given is not None and stored.get(key) is not None and given != stored[key]:
            return name, given, stored[key]
    return None
