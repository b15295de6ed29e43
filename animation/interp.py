"""Decoder-side FAP interpolation: left/right fill and the FAP Interpolation Table (FIT).

Order of operations per frame (engine): bitstream values -> FIT -> left/right fill ->
high-level (visemes/expressions). Reasons: the FIT is the sender's explicit rule for
FAPs it left free, so it is applied first; left/right fill is the Simple profile's fixed
rule (IST 3.5.2) for what the FIT did not cover; visemes/expressions may only touch FAPs
still free after that (IST 3.1.1). Every step writes only FAPs whose status is FREE and
marks what it wrote DERIVED; SET/RETAINED values are never changed.

Left/right fill (IST 3.5.2 / 3.6): for each pair (l, r) of ``tables.left_right_pairs()``,
when one side is SET/RETAINED/DERIVED and the other is FREE, the free side gets the same
value (status DERIVED). Plain copy: the table's directions are mirror images (e.g. FAP 6
positive = left, FAP 7 positive = right), so equal values give symmetric motion.

FIT (Ostermann 1998 3.3, eq. 1; BIFS fields spec notes 6) -- how fbaconf reads the flat
fields:

* ``FAPs``: the FAP numbers of each graph node, nodes separated by -1 (a trailing -1 is
  optional). Node i = the i-th group (0-based).
* ``Graph``: pairs (parent node, child node); the order of the pairs for the same child
  is the parent order (1st parent first).
* For each link in ``Graph`` order, for each FAP of its child node in node order: one
  rational function of the parent node's FAPs F_1..F_n:
  ``numeratorTerms[f]`` terms (K), ``denominatorTerms[f]`` terms (P) -- one entry each
  per function; ``numeratorCoefs`` / ``denominatorCoefs``: one coefficient per term;
  ``numeratorExp`` / ``denominatorExp``: n exponents per term (the powers of F_1..F_n);
  ``numeratorImpulse``: empty, or one entry per numerator term: 0 = none, k >= 1 = the
  term is multiplied by the impulse delta(F_k) (1 when the k-th parent FAP is 0, else 0)
  -- a reading [?] of a field the public sources do not describe.
  All lists are consumed sequentially; a count mismatch is a SceneError.
  ``denominatorTerms = 0`` means denominator 1.
* FAP 1 / FAP 2 may appear in parent nodes; their value is viseme_blend /
  expression_intensity1 (available when FAP 1 / 2 is not FREE). They cannot be children.
* Evaluation: child nodes in topological order of the graph (a cycle is a SceneError).
  A child node is interpolated in the frames where one of its FAPs is FREE, from the first
  parent (in link order) whose FAPs are all available (status not FREE, including values
  DERIVED earlier in the same pass); only its FREE FAPs are written (DERIVED).
  A denominator that evaluates to 0 in a frame where it is used is a SceneError naming
  frame and FAP (never NaN/inf).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fbaconf.bitstreams.frames import DERIVED, FREE
from fbaconf.bitstreams.tables import NUM_FAPS, left_right_pairs
from fbaconf.errors import SceneError


def lr_fill(values: np.ndarray, status: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Copy one side of a left/right pair to the other where only one side has a value."""
    values = np.array(values, dtype=np.float64)
    status = np.array(status, dtype=np.uint8)
    done = set()
    for a, b in left_right_pairs():
        if (b, a) in done:
            continue
        done.add((a, b))
        ia, ib = a - 1, b - 1
        has_a, has_b = status[:, ia] != FREE, status[:, ib] != FREE
        to_b = has_a & ~has_b
        to_a = has_b & ~has_a
        values[to_b, ib] = values[to_b, ia]
        values[to_a, ia] = values[to_a, ib]
        status[to_b, ib] = DERIVED
        status[to_a, ia] = DERIVED
    return values, status


@dataclass
class RationalFunction:
    num_coefs: np.ndarray  # [K]
    num_exps: np.ndarray  # [K, n]
    num_impulse: np.ndarray  # [K] 0 = none, k = delta(F_k)
    den_coefs: np.ndarray  # [P]
    den_exps: np.ndarray  # [P, n]

    @staticmethod
    def _poly(coefs, exps, F, impulse=None):
        # F: [frames, n]; sum_i c_i prod_j F_j^e_ij
        if coefs.size == 0:
            return np.zeros(F.shape[0])
        terms = np.prod(F[:, None, :] ** exps[None, :, :], axis=2)  # [frames, K]
        if impulse is not None and np.any(impulse):
            for t, k in enumerate(impulse):
                if k:
                    terms[:, t] *= F[:, k - 1] == 0
        return terms @ coefs

    def evaluate(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(numerator, denominator) for parent values F [frames, n]."""
        with np.errstate(all="ignore"):
            num = self._poly(self.num_coefs, self.num_exps, F, self.num_impulse)
            den = np.ones(F.shape[0]) if self.den_coefs.size == 0 else self._poly(self.den_coefs, self.den_exps, F)
        return num, den


@dataclass
class FitLink:
    parent: int
    child: int
    functions: list[RationalFunction]  # one per FAP of the child node


@dataclass
class FitGraph:
    nodes: list[list[int]]
    links: list[FitLink]
    order: list[int] = field(default_factory=list)  # child nodes in topological order

    @classmethod
    def from_node(cls, node, *, node_path: str | None = None) -> FitGraph:
        """The graph of a FIT scene node (anything with ``get(field name)``)."""
        return cls.from_fields(
            node.get("FAPs"), node.get("Graph"), {k: node.get(k) for k in FIT_FUNCTION_FIELDS}, node_path=node_path
        )

    @classmethod
    def from_fields(cls, faps, graph, functions=None, *, node_path: str | None = None) -> FitGraph:
        """The graph from the FIT node's ``FAPs`` and ``Graph`` fields and its function fields
        (``functions``: FIT field name -> values, those of :data:`FIT_FUNCTION_FIELDS`; a
        missing one is empty). Raises :class:`SceneError` naming the field and the rule."""
        p = (node_path + ".") if node_path else ""

        def err(msg, fld, rule):
            return SceneError(msg, rule=rule, node_path=p + fld)

        nodes = _fit_nodes([int(x) for x in faps], err)
        pairs = _fit_pairs([int(x) for x in graph], nodes, err)
        given = functions or {}
        fields = _FieldCursor(
            {k: [_FIELD_TYPE[k](x) for x in (() if given.get(k) is None else given[k])] for k in FIT_FUNCTION_FIELDS},
            err,
        )
        use_impulse = len(fields.lists["numeratorImpulse"]) > 0
        links = [
            FitLink(a, b, [_fit_function(fields, (a, b), len(nodes[a]), use_impulse, err) for _ in nodes[b]])
            for a, b in pairs
        ]
        fields.check_used()
        g = cls(nodes, links)
        g.order = g._topological(err)
        return g

    def _topological(self, err) -> list[int]:
        children = {}
        indeg = {i: 0 for i in range(len(self.nodes))}
        for ln in self.links:
            children.setdefault(ln.parent, []).append(ln.child)
            indeg[ln.child] += 1
        ready = sorted(i for i, d in indeg.items() if d == 0)
        order = []
        while ready:
            i = ready.pop(0)
            order.append(i)
            for c in children.get(i, []):
                indeg[c] -= 1
                if indeg[c] == 0:
                    ready.append(c)
            ready.sort()
        if len(order) != len(self.nodes):
            cyc = sorted(i for i, d in indeg.items() if d > 0)
            raise err(f"the FAP interpolation graph has a cycle through nodes {cyc}", "Graph", "fit-cycle")
        has_parent = {ln.child for ln in self.links}
        return [i for i in order if i in has_parent]

    def apply(
        self, values: np.ndarray, status: np.ndarray, high: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Interpolate FREE FAPs; returns new (values float64[F, 68], status uint8[F, 68])."""
        values = np.array(values, dtype=np.float64)
        status = np.array(status, dtype=np.uint8)
        F = values.shape[0]
        ext = np.zeros((F, NUM_FAPS))
        ext[:] = values
        if high is not None:
            ext[:, 0] = np.asarray(high)[:, 2]  # FAP 1 value: viseme_blend
            ext[:, 1] = np.asarray(high)[:, 5]  # FAP 2 value: expression_intensity1
        for child in self.order:
            cidx = np.array(self.nodes[child]) - 1
            need = (status[:, cidx] == FREE).any(axis=1)
            for ln in (l for l in self.links if l.child == child):
                if not need.any():
                    break
                pidx = np.array(self.nodes[ln.parent]) - 1
                avail = need & (status[:, pidx] != FREE).all(axis=1)
                if not avail.any():
                    continue
                rows = np.nonzero(avail)[0]
                Fp = ext[np.ix_(rows, pidx)]
                for fap_idx, fn in zip(cidx, ln.functions):
                    num, den = fn.evaluate(Fp)
                    bad = (den == 0) | ~np.isfinite(num) | ~np.isfinite(den)
                    free_here = status[rows, fap_idx] == FREE
                    if np.any(bad & free_here):
                        k = int(rows[np.nonzero(bad & free_here)[0][0]])
                        raise SceneError(
                            f"FIT link ({ln.parent} -> {child}) for FAP {fap_idx + 1}: denominator is 0 "
                            f"(or the value overflows) in frame {k}",
                            rule="fit-division-by-zero",
                            node_path="FIT",
                        )
                    with np.errstate(all="ignore"):
                        val = num / np.where(den == 0, 1.0, den)
                    w = rows[free_here]
                    values[w, fap_idx] = val[free_here]
                    ext[w, fap_idx] = val[free_here]
                    status[w, fap_idx] = DERIVED
                need &= ~avail
        return values, status


# The FIT node's function fields (ISO/IEC 14496-2 FIT; layout in docs/animation.md) and their types.
FIT_FUNCTION_FIELDS = (
    "numeratorExp",
    "denominatorExp",
    "numeratorImpulse",
    "numeratorTerms",
    "denominatorTerms",
    "numeratorCoefs",
    "denominatorCoefs",
)
_FIELD_TYPE = {
    "numeratorExp": int,
    "denominatorExp": int,
    "numeratorImpulse": int,
    "numeratorTerms": int,
    "denominatorTerms": int,
    "numeratorCoefs": float,
    "denominatorCoefs": float,
}


def _fit_nodes(faps: list[int], err) -> list[list[int]]:
    """The FAPs field split at -1 into nodes, each non-empty and without a FAP twice."""
    nodes: list[list[int]] = [[]]
    for x in faps:
        if x == -1:
            nodes.append([])
        elif 1 <= x <= NUM_FAPS:
            nodes[-1].append(x)
        else:
            raise err(f"FAP number {x} out of range (-1 separator or 1..68)", "FAPs", "fit-fap-range")
    if nodes and not nodes[-1]:
        nodes.pop()
    for i, nd in enumerate(nodes):
        if not nd:
            raise err(f"FIT node {i} has no FAPs", "FAPs", "fit-empty-node")
        if len(set(nd)) != len(nd):
            raise err(f"FIT node {i} lists a FAP twice", "FAPs", "fit-duplicate-fap")
    return nodes


def _fit_pairs(graph: list[int], nodes: list[list[int]], err) -> list[tuple[int, int]]:
    """The Graph field's (parent, child) links, each between two existing nodes, no self-loop,
    no high-level FAP in a child, no link twice."""
    if len(graph) % 2:
        raise err("Graph must hold (parent, child) pairs", "Graph", "fit-graph-pairs")
    pairs = list(zip(graph[0::2], graph[1::2]))
    for a, b in pairs:
        if not (0 <= a < len(nodes) and 0 <= b < len(nodes)):
            raise err(
                f"link ({a}, {b}) names a node that does not exist ({len(nodes)} nodes)", "Graph", "fit-missing-node"
            )
        if a == b:
            raise err(f"link ({a}, {b}) is a self-loop", "Graph", "fit-cycle")
        if any(f in (1, 2) for f in nodes[b]):
            raise err(
                f"node {b} is a child but holds FAP 1/2 (high-level FAPs cannot be interpolated)",
                "Graph",
                "fit-high-level-child",
            )
    if len(set(pairs)) != len(pairs):
        raise err("a link appears twice", "Graph", "fit-duplicate-link")
    return pairs


class _FieldCursor:
    """Reads the function fields in order, each from where the last read stopped."""

    def __init__(self, lists: dict[str, list], err) -> None:
        self.lists, self.err = lists, err
        self.at = dict.fromkeys(lists, 0)

    def take(self, name: str, count: int) -> list:
        c = self.at[name]
        if c + count > len(self.lists[name]):
            raise self.err(
                f"{name} has {len(self.lists[name])} entries, more are needed (function layout: see docs/animation.md)",
                name,
                "fit-field-count",
            )
        self.at[name] = c + count
        return self.lists[name][c : c + count]

    def check_used(self) -> None:
        for name, c in self.at.items():
            if c != len(self.lists[name]):
                raise self.err(
                    f"{name} has {len(self.lists[name])} entries but the graph uses {c}", name, "fit-field-count"
                )


def _fit_function(fields: _FieldCursor, link: tuple[int, int], n: int, use_impulse: bool, err) -> RationalFunction:
    """The next rational function of ``link`` (its parent node has ``n`` FAPs)."""
    K, P = fields.take("numeratorTerms", 1)[0], fields.take("denominatorTerms", 1)[0]
    if K < 0 or P < 0:
        raise err("term counts must be >= 0", "numeratorTerms", "fit-field-count")
    nc = np.array(fields.take("numeratorCoefs", K), dtype=np.float64)
    ne = np.array(fields.take("numeratorExp", K * n), dtype=np.float64).reshape(K, n)
    ni = np.array(fields.take("numeratorImpulse", K) if use_impulse else [0] * K, dtype=np.int64)
    if np.any((ni < 0) | (ni > n)):
        raise err(f"numeratorImpulse entries must be 0..{n}", "numeratorImpulse", "fit-impulse")
    dc = np.array(fields.take("denominatorCoefs", P), dtype=np.float64)
    de = np.array(fields.take("denominatorExp", P * n), dtype=np.float64).reshape(P, n)
    if np.any(ne < 0) or np.any(de < 0):
        raise err("exponents must be >= 0", "numeratorExp", "fit-exponent")
    if not (np.all(np.isfinite(nc)) and np.all(np.isfinite(dc))):
        raise err("coefficients must be finite", "numeratorCoefs", "fit-coef-finite")
    if P > 0 and not np.any(dc != 0):
        raise err(f"link {link}: denominator is identically 0", "denominatorCoefs", "fit-division-by-zero")
    return RationalFunction(nc, ne, ni, dc, de)
