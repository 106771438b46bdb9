"""How well can one drive tell Qc without ground truth? The Cramér-Rao bound of `rodo calibrate --no-truth`.

EM learns the jerk PSD q_i from the estimator's posteriors (`validation.calibrate.em_qc`). Whatever the method, a
drive holds a finite amount of information about each q_i, and the Cramér-Rao bound turns it into the smallest
standard deviation of log q_i that an unbiased estimator can reach on that drive. It is computed here in a
linear-Gaussian surrogate of the drive:

    x_k = F_k x_{k-1} + w_k,  w_k ~ N(0, Q_k(q)),  Q_k(q) = sum_i q_i B_k^(i)  (the prior along the estimate),
    each scan measures x_k with the information the estimator's covariances say it added (`em_surrogate.surrogates`):
    Lambda_k = P_k^-1 - (F_k P_{k-1} F_k^T + Q_k(q_run))^-1, its PSD part where it carries information (the stand-in
    EM runs in, `em_surrogate`).

Its Fisher information of log q is the variance of the score (`fisher_information`): by Fisher's identity the
data's score is the complete-data score (`calibrate.expected_log_likelihood`'s gradient) expected under the
smoother, so datasets drawn from the surrogate, each smoothed, give the score's variance by Monte Carlo. The
smoother's covariances do not depend on the data; only the means are drawn.

It is a bound at best: the surrogate takes each scan's information as independent and as large as the window's
covariance claims, and that covariance is over-confident in pose (docs/consistency.md), so the data hold at most
this much. A component whose bound is wide is not learned by any method from this drive; one whose bound is
narrow may still be biased (EM books the estimator's correlated errors as motion: the velocity-growth check).

Checked by: tests/validation/test_qc_information.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.errors import InputError

from . import calibrate as cal
from .em_surrogate import filter_covariances, spd_inverse, surrogates

WITHIN = 0.25  # the relative accuracy asked of Qc without truth (issue 15)
SD_FOR_WITHIN = 0.125  # SD of log q that puts an unbiased estimate within 25 % with 95 % probability
SAMPLES = 2000  # Monte Carlo datasets for the score's variance (a well-determined bound then known to about 2 %)
CHUNK_VALUES = 5e6  # numbers per array of one chunk of datasets (`fisher_information`; 40 MB)


def _sqrt_psd(A: np.ndarray) -> np.ndarray:
    """L with L L^T = A for PSD matrices (..., d, d) (eigendecomposition: A may be singular)."""
    vals, vecs = np.linalg.eigh(A)
    return vecs * np.sqrt(np.clip(vals, 0.0, None))[..., None, :]


def fisher_information(F, B, q, info, P0, samples: int = SAMPLES, rng: np.random.Generator | None = None):
    """The Fisher information (m, m) of log q in the surrogate x_k = F_k x_{k-1} + w_k, w_k ~ N(0, sum_i q_i
    B_k^(i)), x_0 ~ N(0, P0), each x_k measured with information info_k: the variance over `samples` datasets of
    the score d log p(data) / d log q_i = q_i / 2 sum_k tr(Q_k^-1 B_k^(i) Q_k^-1 S_k) + const, S_k = e_k e_k^T +
    (data-independent), e_k the smoothed prior residual (Fisher's identity).

    Args:
        F: (K, d, d) transitions; B: (K, m, d, d) noise basis; q: (m,); info: (K + 1, d, d) PSD; P0: (d, d).

    Checked by: tests/validation/test_qc_information.py::test_the_score_variance_is_the_exact_fisher_information
    """
    F, B, info = (np.asarray(a, dtype=float) for a in (F, B, info))
    q = np.asarray(q, dtype=float)
    K, d = F.shape[0], F.shape[-1]
    if B.shape[0] != K or B.shape[2:] != (d, d) or B.shape[1] != q.shape[0] or info.shape != (K + 1, d, d):
        raise InputError(f"fisher_information: F {F.shape}, B {B.shape}, q {q.shape}, info {info.shape} do not match")
    rng = np.random.default_rng(np.random.SeedSequence(0)) if rng is None else rng
    Q = cal.process_noise(q, B)
    P, _, Pp_inv, C = filter_covariances(F, Q, info, np.asarray(P0, dtype=float))
    Q_inv = spd_inverse(Q)
    model = (F, B, q, info, P, Pp_inv, C, _sqrt_psd(np.asarray(P0, dtype=float)), _sqrt_psd(Q), _sqrt_psd(info),
             Q_inv[:, None] @ B @ Q_inv[:, None])
    chunk = max(16, int(CHUNK_VALUES // ((K + 1) * d)))  # datasets at a time: memory bounded on long drives
    scores = [_scores(model, min(chunk, samples - start), rng) for start in range(0, samples, chunk)]
    return np.atleast_2d(np.cov(np.concatenate(scores), rowvar=False))


def _scores(model, n: int, rng: np.random.Generator) -> np.ndarray:
    """The scores (n, m) of n datasets drawn from the surrogate (`fisher_information`): x_k drawn, z_k = info_k x_k
    + noise of covariance info_k (information form), filtered and smoothed."""
    F, B, q, info, P, Pp_inv, C, root_P0, root_Q, root_info, W = model
    K, d = F.shape[0], F.shape[-1]
    x = np.empty((K + 1, n, d))
    x[0] = rng.standard_normal((n, d)) @ root_P0.T
    for k in range(1, K + 1):
        x[k] = x[k - 1] @ F[k - 1].T + rng.standard_normal((n, d)) @ root_Q[k - 1].T
    z = np.einsum("kab,ksb->ksa", info, x) + np.einsum("kab,ksb->ksa", root_info, rng.standard_normal(x.shape))
    means, predicted = np.empty_like(x), np.zeros_like(x)  # the filtered, then the smoothed, means
    means[0] = z[0] @ P[0].T
    for k in range(1, K + 1):
        predicted[k] = means[k - 1] @ F[k - 1].T
        means[k] = (predicted[k] @ Pp_inv[k].T + z[k]) @ P[k].T
    for k in range(K - 1, -1, -1):
        means[k] = means[k] + (means[k + 1] - predicted[k + 1]) @ C[k].T
    e = means[1:] - np.einsum("kab,ksb->ksa", F, means[:-1])
    return 0.5 * np.einsum("ksa,kiab,ksb->si", e, W, e) * q


def qc_bound(kind: str, track: cal.StateTrack, qc, qc_run, learned=None, samples: int = SAMPLES,
             seed: int = 0) -> list[dict]:
    """The Cramér-Rao bound of each learned component of Qc = diag(qc) on this drive (`track`: the estimator's
    per-scan posteriors, run with Qc = diag(qc_run)), the others taken as known: rows of component, qc, sd_log
    (the bound on the SD of log q_i; None where the drive holds no information), within_95 (sd_log <=
    SD_FOR_WITHIN: an unbiased estimate lands within 25 % with 95 % probability). Segments broken by a
    re-initialisation add their information; each draws from its own stream of SeedSequence(seed).

    Checked by: tests/validation/test_qc_information.py::test_the_bound_of_a_drive
    """
    qc = np.asarray(qc, dtype=float)
    learned = np.ones(6, bool) if learned is None else np.asarray(learned, dtype=bool)
    parts = surrogates(kind, track, qc_run)
    total = np.zeros((6, 6))
    for s, stream in zip(parts, np.random.SeedSequence(seed).spawn(len(parts))):
        total += fisher_information(s.F, s.B, qc, s.state_information, s.P0, samples, np.random.default_rng(stream))
    sub = total[np.ix_(learned, learned)]
    vals, vecs = np.linalg.eigh(sub)
    informative = vals > 1e-12 * max(float(vals.max()), 1e-300)
    with np.errstate(divide="ignore"):  # a direction without information: an infinite bound where it reaches
        inv_diag = np.where(informative, vecs**2 / np.where(informative, vals, 1.0),
                            np.where(vecs**2 > 1e-20, np.inf, 0.0)).sum(axis=1)
    sd = np.full(6, np.inf)
    sd[learned] = np.sqrt(inv_diag)
    return [{"component": c, "qc": float(q), "learned": bool(on),
             "sd_log": float(v) if on and np.isfinite(v) else None, "within_95": bool(on and v <= SD_FOR_WITHIN)}
            for c, q, on, v in zip(cal.COMPONENTS, qc, learned, sd)]


def drive_needed(sd_log: float | None, duration: float) -> float | None:
    """The drive length (s) at which this drive's bound would reach SD_FOR_WITHIN, the information growing with the
    length (sd ~ 1 / sqrt(T)); None without information."""
    return None if sd_log is None else float(duration * (sd_log / SD_FOR_WITHIN) ** 2)


def bound_header(rows: list[dict]) -> list[str]:
    """The config header's line: the learned components this drive cannot determine within 25 %."""
    off = [r["component"] for r in rows if r["learned"] and not r["within_95"]]
    return [f"BOUND: this drive cannot determine {', '.join(off)} within {WITHIN * 100:.0f} % by any method (Cramer-Rao "
            "bound, the .md report; docs/calibration.md, \"What a drive can tell\")."] if off else []


def bound_lines(rows: list[dict], duration: float) -> list[str]:
    """The bound as a Markdown table with the drive length each component would need."""
    lines = [f"The Cramer-Rao bound of this drive ({duration:.0f} s; docs/calibration.md, \"What a drive can tell\"): "
             f"the smallest SD of log q that any unbiased estimate can have, at EM's Qc, at best (it takes each "
             f"scan's information as the estimator's covariances claim it). {WITHIN * 100:.0f} % with 95 % probability needs "
             f"{SD_FOR_WITHIN:g} or less.", "",
             "| component | Qc | bound on SD(log q) | within 25 % | drive length it needs (s) |",
             "| --- | --- | --- | --- | --- |"]
    for r in rows:
        if not r["learned"]:
            lines.append(f"| {r['component']} | {r['qc']:.3g} | - (not learned) | - | - |")
            continue
        sd, need = r["sd_log"], drive_needed(r["sd_log"], duration)
        lines.append(f"| {r['component']} | {r['qc']:.3g} | {'no information' if sd is None else f'{sd:.3g}'} | "
                     f"{'yes' if r['within_95'] else '**no**'} | {'-' if need is None else f'{need:.0f}'} |")
    return lines
