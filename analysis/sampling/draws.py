"""emcee's random draws of differential-evolution steps, taken many steps at a time from the same stream.

emcee's red-blue DEMove draws, at every step and from one numpy RandomState, in this
order: one uniform (its choice among the moves), a shuffle of the walkers' split labels,
then for each sub-ensemble the indices of its difference pairs (`randint`), one normal
per walker for the step size (`randn`) and one uniform per walker for the acceptance
(`rand`). None of these depends on the walkers' positions, so the draws of a block of
steps can be taken at once before the steps are run. `de_draws` does so with numpy's
own algorithms over the RandomState's Mersenne Twister (MT19937) state, so the stream,
and hence the chain, is the one emcee draws bit for bit:

- 32-bit words: MT19937 with its tempering (numpy's mt19937_next);
- uniforms: 53 bits from two words, (a >> 5, b >> 6) (mt19937_next_double);
- `randint(0, n)`: a word masked to the smallest 2^k - 1 >= n - 1, drawn again while
  above n - 1 (numpy's buffered_bounded_masked_uint32, RandomState's default);
- `shuffle`: Fisher-Yates from the last element, `random_interval` (the same masking);
- `randn`: the legacy polar method, whose second value is kept for the next call.

`take_state` and `give_state` move the state out of and back into the RandomState.
`propose` and `accept` are the step's arithmetic in one pass over a sub-ensemble: the
proposal x_k + gamma_k (x_b - x_a) and emcee's test log p(q_k) - log p(x_k) > log u_k,
the same floating-point operations in the same order as numpy's arrays.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from dynid.numba_cache import install as _cache_outside_the_package

_cache_outside_the_package()   # before the first @njit(cache=True): dynid.numba_cache

_N, _M = 624, 397


@njit(cache=True, nogil=True)
def _regenerate(key):
    for i in range(_N - _M):
        y = (key[i] & 0x80000000) | (key[i + 1] & 0x7FFFFFFF)
        key[i] = key[i + _M] ^ (y >> 1) ^ (-(y & 1) & 0x9908B0DF)
    for i in range(_N - _M, _N - 1):
        y = (key[i] & 0x80000000) | (key[i + 1] & 0x7FFFFFFF)
        key[i] = key[i + _M - _N] ^ (y >> 1) ^ (-(y & 1) & 0x9908B0DF)
    y = (key[_N - 1] & 0x80000000) | (key[0] & 0x7FFFFFFF)
    key[_N - 1] = key[_M - 1] ^ (y >> 1) ^ (-(y & 1) & 0x9908B0DF)


@njit(cache=True, nogil=True)
def _word(key, pos):
    """(the next 32-bit word, the new position in the key); the position is passed along as a
    scalar so that the compiled loops keep it in a register."""
    if pos >= _N:
        _regenerate(key)
        pos = 0
    y = key[pos]
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y, pos + 1


@njit(cache=True, nogil=True)
def _uniform(key, pos):
    a, pos = _word(key, pos)
    b, pos = _word(key, pos)
    return ((a >> 5) * 67108864.0 + (b >> 6)) / 9007199254740992.0, pos


@njit(cache=True, nogil=True)
def _mask(n):
    m = n
    m |= m >> 1
    m |= m >> 2
    m |= m >> 4
    m |= m >> 8
    m |= m >> 16
    return m


@njit(cache=True, nogil=True)
def _bounded(key, pos, top, mask):
    """Uniform integer in [0, top] (top < 2^32) by masking and rejection."""
    v, pos = _word(key, pos)
    v &= mask
    while v > top:
        v, pos = _word(key, pos)
        v &= mask
    return v, pos


@njit(cache=True, nogil=True)
def _gauss(key, pos, cache):
    """numpy's legacy_gauss; cache = [has_gauss, gauss]."""
    if cache[0] != 0.0:
        v = cache[1]
        cache[0] = 0.0
        cache[1] = 0.0
        return v, pos
    while True:
        u1, pos = _uniform(key, pos)
        u2, pos = _uniform(key, pos)
        x1 = 2.0 * u1 - 1.0
        x2 = 2.0 * u2 - 1.0
        r2 = x1 * x1 + x2 * x2
        if r2 < 1.0 and r2 != 0.0:
            break
    f = math.sqrt(-2.0 * math.log(r2) / r2)
    cache[1] = f * x1
    cache[0] = 1.0
    return f * x2, pos


@njit(cache=True, nogil=True)
def _de_draws(key, st, cache, labels, nsplits, randomize, first, second, order, ia, ib, normals, uniforms):
    n_steps, nw = order.shape
    half = nw // nsplits
    inds = np.empty(nw, np.int64)
    other = np.empty(nw - half, np.int64)
    top = first.size - 1
    mask = _mask(top)
    pos = st[0]
    for s in range(n_steps):
        _, pos = _uniform(key, pos)              # emcee's choice among the moves
        inds[:] = labels
        if randomize:
            for i in range(nw - 1, 0, -1):
                j, pos = _bounded(key, pos, i, _mask(i))
                t = inds[i]
                inds[i] = inds[j]
                inds[j] = t
        k = 0
        for sp in range(nsplits):                # each sub-ensemble in walker order (a stable sort)
            for w in range(nw):
                if inds[w] == sp:
                    order[s, k] = w
                    k += 1
        for sp in range(nsplits):
            k = 0
            for sp2 in range(nsplits):           # the complement: the other sub-ensembles in order
                if sp2 != sp:
                    for m in range(half):
                        other[k] = order[s, sp2 * half + m]
                        k += 1
            base = sp * half
            for m in range(half):
                p, pos = _bounded(key, pos, top, mask)
                ia[s, base + m] = other[first[p]]
                ib[s, base + m] = other[second[p]]
            for m in range(half):
                normals[s, base + m], pos = _gauss(key, pos, cache)
            for m in range(half):
                uniforms[s, base + m], pos = _uniform(key, pos)
    st[0] = pos


class StreamState:
    """A RandomState's MT19937 state as arrays the compiled draws advance in place."""

    def __init__(self, random: np.random.RandomState):
        name, key, pos, has_gauss, gauss = random.get_state(legacy=True)
        if name != "MT19937":
            raise ValueError(f"not a Mersenne Twister stream: {name}")
        self.key = np.asarray(key, dtype=np.int64).copy()
        self.pos = np.array([pos], dtype=np.int64)
        self.cache = np.array([float(has_gauss), float(gauss)])

    def copy(self) -> StreamState:
        out = object.__new__(StreamState)
        out.key, out.pos, out.cache = self.key.copy(), self.pos.copy(), self.cache.copy()
        return out

    def give(self, random: np.random.RandomState) -> None:
        """Set `random` to this state (the draws taken so far count as drawn from it)."""
        random.set_state(("MT19937", self.key.astype(np.uint32), int(self.pos[0]),
                          int(self.cache[0]), float(self.cache[1])))


class DEDraws:
    """The draws of `n_steps` DE steps: walker order, difference pairs, normals and uniforms,
    each (n_steps, nsplits, n_walkers / nsplits), row s of sub-ensemble k in the order emcee
    draws them."""

    def __init__(self, stream: StreamState, n_steps, n_walkers, nsplits, randomize, first, second):
        shape = (n_steps, n_walkers)
        self.order = np.empty(shape, np.int64)
        self.ia = np.empty(shape, np.int64)
        self.ib = np.empty(shape, np.int64)
        self.normals = np.empty(shape)
        self.uniforms = np.empty(shape)
        labels = np.arange(n_walkers, dtype=np.int64) % nsplits
        _de_draws(stream.key, stream.pos, stream.cache, labels, int(nsplits), bool(randomize),
                  np.asarray(first, dtype=np.int64), np.asarray(second, dtype=np.int64),
                  self.order, self.ia, self.ib, self.normals, self.uniforms)
        split = (n_steps, nsplits, n_walkers // nsplits)
        for name in ("order", "ia", "ib", "normals", "uniforms"):
            setattr(self, name, getattr(self, name).reshape(split))


@njit(cache=True, nogil=True)
def propose(coords, order, ia, ib, gamma, s, split, q):
    """Sub-ensemble `split` of step `s` of a `DEDraws` block: q[k] = coords[i] + gamma * (coords[b] -
    coords[a]) with i = order[s, split, k], a = ia[s, split, k], b = ib[s, split, k], gamma =
    gamma[s, split, k] (the arrays of the block are passed whole: one call, no views)."""
    d = coords.shape[1]
    for k in range(q.shape[0]):
        g = gamma[s, split, k]
        i, a, b = order[s, split, k], ia[s, split, k], ib[s, split, k]
        for j in range(d):
            q[k, j] = coords[i, j] + g * (coords[b, j] - coords[a, j])


@njit(cache=True, nogil=True)
def accept(coords, lp, order, s, split, q, new_lp, log_u, accepted):
    """emcee's test new_lp[k] - lp[w] > log_u[s, split, k] for walker w = order[s, split, k]; an
    accepted walker takes q[k] and new_lp[k], and accepted[w] is set."""
    d = coords.shape[1]
    for k in range(q.shape[0]):
        w = order[s, split, k]
        if new_lp[k] - lp[w] > log_u[s, split, k]:
            for j in range(d):
                coords[w, j] = q[k, j]
            lp[w] = new_lp[k]
            accepted[w] = True
