"""The serial peer of ``jaxplan.tune.ranking``'s listwise loss: plain Python loops over expansions,
gaps and presearch leaves (``math``, no JAX, no numpy vector algebra)."""
from __future__ import annotations

import math

__all__ = ["reference_ranking_loss"]


def reference_ranking_loss(params, data, temperature: float) -> float:
    """``jaxplan.tune.ranking_loss`` by loops: per expansion, Eq. 9's cost of each valid gap (its
    one-hop cost, the least tail over its masked leaves, its penalty), the log-softmax of ``-cost /
    temperature`` over the valid gaps, the cross-entropy to the target, weighted mean over expansions."""
    lt, lp, eta = float(params.lambda_t), float(params.lambda_p), float(params.eta)
    first, tail, mask, penalty = (x.tolist() for x in map(_host, data.features))
    valid, target, weight = _host(data.valid).tolist(), _host(data.target).tolist(), _host(data.weight).tolist()
    total = wsum = 0.0
    for e in range(len(first)):
        logits = []
        for k in range(len(first[e])):
            if not valid[e][k]:
                continue
            best = min(lt * t[0] + lp * t[1] + eta * t[2] for t, m in zip(tail[e][k], mask[e][k]) if m)
            cost = lt * first[e][k][0] + lp * first[e][k][1] + best + penalty[e][k]
            logits.append((k, -cost / temperature))
        top = max(z for _, z in logits)
        lse = top + math.log(sum(math.exp(z - top) for _, z in logits))
        total += weight[e] * sum(-target[e][k] * (z - lse) for k, z in logits)
        wsum += weight[e]
    return total / max(wsum, 1e-12)


def _host(x):
    import numpy as np  # noqa: PLC0415 (only to bring device arrays to lists)
    return np.asarray(x)
