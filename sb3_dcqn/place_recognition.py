"""Place recognition: which remembered place a goal photo shows, when it matches no remembered vector exactly.

A route memory keeps every distinct ``achieved_goal`` vector it has seen (its **places**: rows of a float32 array
``(n, d)``), and labels the rows seen at one state with one place identity: the same place pictured in different
conditions (time of day, passing cars). A goal photo taken in a condition the memory never saw matches no row exactly;
a :class:`PlaceMatcher` then names the remembered row it shows, or ``-1``: "not in memory".

- :class:`NearestPlace`: the nearest reference by cosine similarity (in an embedding's space when given), answered
  only above a threshold. :meth:`NearestPlace.calibrate` sets the threshold from the references themselves (the rule
  is in its docstring), or the user gives it.
- :class:`PlaceEmbedding`: a small learned map (one linear layer, or one hidden layer, unit-norm output) trained on
  the references with a supervised contrastive loss over their labels (SupCon, Khosla et al. 2020: rows of one place
  close, rows of other places far), so that what changes with the condition is left out of the similarity.
- :func:`fit_place_matcher`: a calibrated :class:`NearestPlace`, with a freshly fit :class:`PlaceEmbedding` or on the
  raw vectors.
- :class:`AlignedNearestPlace`: for references of one condition only (the agent's own views): a photo of another
  condition is moved into theirs feature by feature (per-feature moments, from the photo's own views and the other
  goal photos asked about), then answered only where one place is clearly the nearest (Lowe's ratio test); where
  none is, a photo of another condition names the few places nearly as near (:meth:`AlignedNearestPlace.candidates`).
  The route memory's default matcher where an env declares goal pictures.

Only numpy and torch are used: the module serves any goal-conditioned env whose goals are vectors.
"""

from __future__ import annotations

import itertools
from typing import Protocol, runtime_checkable

import numpy as np
import torch as th

__all__ = [
    "NOT_IN_MEMORY",
    "AlignedNearestPlace",
    "CandidateMatcher",
    "NearestPlace",
    "PlaceEmbedding",
    "PlaceMatcher",
    "fit_place_matcher",
]

PROBE_SHARE = 0.2  # places left out of the probe embedding that calibrates a learned matcher's threshold
NOT_IN_MEMORY = -1  # the answer for a query no remembered place is close enough to
NORM_EPS = 1e-12  # a zero vector stays zero when normalised (its similarity to everything is 0)


@runtime_checkable
class PlaceMatcher(Protocol):
    """What a route memory asks when a goal photo matches none of its place vectors exactly."""

    def match(
        self, queries: np.ndarray, references: np.ndarray, labels: np.ndarray, goal_pictures: np.ndarray | None = None
    ) -> np.ndarray:
        """
        :param queries: ``(m, d)`` float32 goal photos
        :param references: ``(n, d)`` float32 the memory's place vectors
        :param labels: ``(n,)`` int64 the place identity of each reference (rows seen at one state share a label)
        :param goal_pictures: ``(k, d)`` every goal photo the memory was shown so far (unlabelled: the goals' own
            conditions, for a matcher that aligns them with the references'); a matcher may ignore it
        :return: ``(m,)`` int64: the matched reference ROW for each query, or -1: "not in memory" (no remembered place
            is close enough)
        """
        ...


@runtime_checkable
class CandidateMatcher(PlaceMatcher, Protocol):
    """A :class:`PlaceMatcher` that can also name the few places a photo may show where it cannot name one: a route
    memory then visits them, and each where the goal's episode goes on is ruled out."""

    def candidates(
        self, queries: np.ndarray, references: np.ndarray, labels: np.ndarray, goal_pictures: np.ndarray | None = None
    ) -> np.ndarray:
        """
        As :meth:`PlaceMatcher.match`, but ``(m, k)`` int64 reference rows per query, the likeliest first (-1 padded):
        the match alone where there is one, several places where the photo may show any of them, none (all -1) where
        it is not in memory.
        """
        ...


def _check_matrix(name: str, array: np.ndarray, dim: int | None = None) -> np.ndarray:
    """``array`` as a finite float32 ``(rows, d)`` matrix, else a ValueError naming ``name`` and its shape."""
    array = np.asarray(array)
    if array.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array (rows, d), got shape {array.shape}")
    if dim is not None and array.shape[1] != dim:
        raise ValueError(f"{name} has {array.shape[1]} columns (shape {array.shape}), expected d = {dim}")
    if not np.issubdtype(array.dtype, np.floating) and not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"{name} must hold numbers, got dtype {array.dtype}")
    array = array.astype(np.float32, copy=False)
    if not np.isfinite(array).all():
        raise ValueError(f"{name} holds NaN or infinite values (shape {array.shape})")
    return array


def _check_labels(labels: np.ndarray, references: np.ndarray) -> np.ndarray:
    """``labels`` as int64 ``(n,)`` matching the references' rows, else a ValueError naming both shapes."""
    labels = np.asarray(labels)
    if labels.ndim != 1 or labels.shape[0] != references.shape[0]:
        raise ValueError(
            f"labels must have shape (n,) with n = references' rows: labels {labels.shape}, "
            f"references {references.shape}"
        )
    if labels.size and not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be integers (place identities), got dtype {labels.dtype}")
    return labels.astype(np.int64, copy=False)


def _unit_rows(vectors: np.ndarray) -> np.ndarray:
    """Each row divided by its norm (cosine similarity is then a dot product)."""
    return vectors / np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), NORM_EPS)


class PlaceEmbedding:
    """
    A small learned embedding of place vectors in which the rows of one place lie close and the rows of other places
    far: inputs are normalised to unit length, mapped by one linear layer (``hidden=None``) or by a hidden layer with
    a ReLU and a linear layer, and normalised again. Trained with the supervised contrastive loss (SupCon, Khosla et
    al. 2020) over the references' labels, full batch (or batches of ``batch_size`` rows drawn with the seed when
    there are more rows): for every anchor row with another row of its place, minus the mean log-softmax (over all
    other rows, temperature ``temperature``) of its same-place rows. Weight decay keeps the map close to a random
    projection in the directions the data does not constrain.

    :param dim: Output dimension
    :param hidden: Width of a hidden layer (``None``: one linear layer)
    :param temperature: Softmax temperature of the contrastive loss
    :param learning_rate: Adam's learning rate
    :param weight_decay: Adam's (decoupled, AdamW) weight decay
    :param batch_size: Rows per training batch at most (all rows when there are fewer)
    """

    def __init__(
        self,
        dim: int = 64,
        hidden: int | None = None,
        temperature: float = 0.5,
        learning_rate: float = 3e-3,
        weight_decay: float = 0.1,
        batch_size: int = 2048,
    ) -> None:
        for name, value in (("dim", dim), ("batch_size", batch_size)):
            if int(value) < 1:
                raise ValueError(f"PlaceEmbedding: {name} must be >= 1, got {value}")
        if hidden is not None and int(hidden) < 1:
            raise ValueError(f"PlaceEmbedding: hidden must be >= 1 or None, got {hidden}")
        if not temperature > 0 or not learning_rate > 0 or weight_decay < 0:
            raise ValueError(
                f"PlaceEmbedding: temperature and learning_rate must be > 0 and weight_decay >= 0, got "
                f"{temperature}, {learning_rate}, {weight_decay}"
            )
        self.dim = int(dim)
        self.hidden = None if hidden is None else int(hidden)
        self.temperature = float(temperature)
        self.learning_rate = float(learning_rate)
        self.weight_decay = float(weight_decay)
        self.batch_size = int(batch_size)
        self.input_dim: int | None = None  # set by fit
        self.losses: list[float] = []  # the training loss at every step of the last fit
        self._net: th.nn.Sequential | None = None

    def _build(self, input_dim: int, generator: th.Generator) -> th.nn.Sequential:
        """The network, its weights drawn from ``generator`` alone (not torch's global seed)."""
        widths = [input_dim, *([] if self.hidden is None else [self.hidden]), self.dim]
        layers: list[th.nn.Module] = []
        for index, (fan_in, fan_out) in enumerate(itertools.pairwise(widths)):
            layer = th.nn.Linear(fan_in, fan_out)
            with th.no_grad():  # a scaled Gaussian: at the start, a random projection that keeps cosines roughly
                layer.weight.copy_(th.randn(fan_out, fan_in, generator=generator) / np.sqrt(fan_in))
                layer.bias.zero_()
            layers.append(layer)
            if index < len(widths) - 2:
                layers.append(th.nn.ReLU())
        return th.nn.Sequential(*layers)

    def fit(self, references: np.ndarray, labels: np.ndarray, steps: int = 300, seed: int = 0) -> PlaceEmbedding:
        """
        Train on the references and their place labels (the same seed gives the same embedding on one thread).

        :param references: ``(n, d)`` place vectors
        :param labels: ``(n,)`` integer place identities; at least one place needs two rows (what to keep close)
        :param steps: Adam steps
        :param seed: Seed of the initial weights and of the batches
        :return: self
        """
        references = _check_matrix("references", references)
        labels = _check_labels(labels, references)
        if int(steps) < 1:
            raise ValueError(f"PlaceEmbedding.fit: steps must be >= 1, got {steps}")
        _, counts = np.unique(labels, return_counts=True)
        if not (counts >= 2).any():
            raise ValueError(
                f"PlaceEmbedding.fit: every one of the {len(counts)} labels has one row: with no place seen twice "
                "there is nothing to learn what stays the same (use NearestPlace on the raw vectors)"
            )
        if len(counts) < 2:
            raise ValueError("PlaceEmbedding.fit: all rows have one label: there is no other place to keep apart")
        generator = th.Generator().manual_seed(int(seed))
        self.input_dim = references.shape[1]
        self._net = self._build(self.input_dim, generator)
        optimizer = th.optim.AdamW(self._net.parameters(), lr=self.learning_rate, weight_decay=self.weight_decay)
        inputs = th.from_numpy(_unit_rows(references))
        targets = th.from_numpy(labels)
        self.losses = []
        self._net.train()
        for _ in range(int(steps)):
            if len(inputs) > self.batch_size:
                batch = th.randperm(len(inputs), generator=generator)[: self.batch_size]
                loss = self._loss(inputs[batch], targets[batch])
            else:
                loss = self._loss(inputs, targets)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            self.losses.append(float(loss.detach()))
        self._net.eval()
        return self

    def _loss(self, inputs: th.Tensor, targets: th.Tensor) -> th.Tensor:
        """The supervised contrastive loss of one batch."""
        embedded = th.nn.functional.normalize(self._net(inputs), dim=1, eps=NORM_EPS)
        logits = embedded @ embedded.T / self.temperature
        itself = th.eye(len(inputs), dtype=th.bool)
        logits = logits.masked_fill(itself, -th.inf)  # a row is never its own positive nor its own negative
        log_prob = logits - th.logsumexp(logits, dim=1, keepdim=True)
        positives = (targets[:, None] == targets[None, :]) & ~itself
        n_positives = positives.sum(dim=1)
        anchors = n_positives > 0  # rows whose place has another row in the batch
        if not anchors.any():  # a drawn batch may hold no pair: nothing to pull together this step
            return (embedded * 0.0).sum()
        positive_log_prob = log_prob.masked_fill(~positives, 0.0).sum(dim=1)
        return -(positive_log_prob[anchors] / n_positives[anchors]).mean()

    def transform(self, vectors: np.ndarray) -> np.ndarray:
        """
        :param vectors: ``(m, d)`` place vectors (the ``d`` the embedding was fit on)
        :return: ``(m, dim)`` float32 unit-norm embeddings
        """
        if self._net is None or self.input_dim is None:
            raise RuntimeError("PlaceEmbedding.transform: call fit(references, labels) first")
        vectors = _check_matrix("vectors", vectors, self.input_dim)
        with th.no_grad():
            embedded = self._net(th.from_numpy(_unit_rows(vectors)))
            return th.nn.functional.normalize(embedded, dim=1, eps=NORM_EPS).numpy().astype(np.float32)


class NearestPlace:
    """
    The nearest reference by cosine similarity (in ``embedding``'s space when given): a query is matched to the
    reference row it is most similar to, and answered ``-1`` ("not in memory") where that similarity is below
    ``threshold``. With ``threshold=None`` (until :meth:`calibrate`), every query gets its nearest row.

    :param threshold: The lowest cosine similarity answered (``None``: no threshold)
    :param embedding: A fitted :class:`PlaceEmbedding` to compare in (``None``: the raw vectors)
    """

    def __init__(self, threshold: float | None = None, embedding: PlaceEmbedding | None = None) -> None:
        if threshold is not None and not -1.0 <= float(threshold) <= 1.0:
            raise ValueError(f"NearestPlace: threshold is a cosine similarity in [-1, 1], got {threshold}")
        self.threshold = None if threshold is None else float(threshold)
        self.embedding = embedding
        # Set by calibrate: the similarities the threshold was chosen from
        self.impostor_similarities: np.ndarray | None = None
        self.genuine_similarities: np.ndarray | None = None

    def _embed(self, vectors: np.ndarray) -> np.ndarray:
        """Unit rows in the space similarities are measured in."""
        return _unit_rows(vectors) if self.embedding is None else self.embedding.transform(vectors)

    def similarities(self, queries: np.ndarray, references: np.ndarray) -> np.ndarray:
        """
        :param queries: ``(m, d)`` vectors
        :param references: ``(n, d)`` vectors
        :return: ``(m, n)`` cosine similarities (in the embedding's space when there is one)
        """
        references = _check_matrix("references", references)
        queries = _check_matrix("queries", queries, references.shape[1])
        return self._embed(queries) @ self._embed(references).T

    def match(
        self, queries: np.ndarray, references: np.ndarray, labels: np.ndarray, goal_pictures: np.ndarray | None = None
    ) -> np.ndarray:
        """
        :param queries: ``(m, d)`` float32 goal photos
        :param references: ``(n, d)`` float32 the memory's place vectors
        :param labels: ``(n,)`` int64 the place identity of each reference
        :param goal_pictures: Unused (the protocol's)
        :return: ``(m,)`` int64: the nearest reference row for each query, or -1 where its similarity is below the
            threshold (and for every query when there are no references)
        """
        references = _check_matrix("references", references)
        queries = _check_matrix("queries", queries, references.shape[1])
        _check_labels(labels, references)
        if len(references) == 0 or len(queries) == 0:
            return np.full(len(queries), NOT_IN_MEMORY, dtype=np.int64)
        similarity = self.similarities(queries, references)
        rows = similarity.argmax(axis=1).astype(np.int64)
        if self.threshold is not None:
            best = similarity[np.arange(len(rows)), rows]
            rows[best < self.threshold] = NOT_IN_MEMORY
        return rows

    def calibrate(self, references: np.ndarray, labels: np.ndarray, rows: np.ndarray | None = None) -> NearestPlace:
        """
        Set the threshold from the references themselves, leaving one row out at a time:

        - **impostor** similarity of a row: its similarity to the nearest row of another place (what a query of a
          place missing from memory would score: it must be rejected);
        - **genuine** similarity of a row (of a place with several rows): its similarity to the nearest other row of
          its own place (what a query of a remembered place in a condition the memory lacks would score: it must be
          answered).

        The threshold minimises the share of impostors at or above it plus the share of genuine rows below it
        (balanced error), at the midpoint of the best interval: when the two sets separate, the midpoint between the
        highest impostor and the lowest genuine similarity. With no place seen twice (no genuine similarity), it is
        the highest impostor similarity: a query is answered only when it is closer to its match than any two
        remembered places are to each other.

        :param references: ``(n, d)`` place vectors, at least two places
        :param labels: ``(n,)`` integer place identities
        :param rows: The rows scored (a boolean mask or row indices; default every row), each against every other
            reference row: :func:`fit_place_matcher` scores places its embedding was not trained on
        :return: self
        """
        references = _check_matrix("references", references)
        labels = _check_labels(labels, references)
        if len(np.unique(labels)) < 2:
            raise ValueError(
                f"NearestPlace.calibrate needs references of at least two places, got labels {np.unique(labels)}"
            )
        scored = np.arange(len(references)) if rows is None else np.arange(len(references))[np.asarray(rows)]
        if scored.size == 0:
            raise ValueError("NearestPlace.calibrate: rows selects no reference row to score")
        similarity = self.similarities(references[scored], references)
        same = labels[scored, None] == labels[None, :]
        similarity[np.arange(len(scored)), scored] = -np.inf  # a row is never its own neighbour
        same[np.arange(len(scored)), scored] = False
        impostor = np.where(same, -np.inf, similarity).max(axis=1)
        genuine = np.where(same, similarity, -np.inf).max(axis=1)
        self.impostor_similarities = impostor[np.isfinite(impostor)]
        self.genuine_similarities = genuine[np.isfinite(genuine)]
        self.threshold = float(
            np.clip(_balanced_threshold(self.impostor_similarities, self.genuine_similarities), -1, 1)
        )
        return self


def _balanced_threshold(impostor: np.ndarray, genuine: np.ndarray) -> float:
    """The threshold of :meth:`NearestPlace.calibrate`: least impostor-accept + genuine-reject share, at a midpoint."""
    impostor, genuine = np.sort(impostor), np.sort(genuine)
    if len(genuine) == 0:
        return float(impostor[-1])
    values = np.unique(np.concatenate([impostor, genuine]))
    if len(values) == 1:
        return float(values[0])
    # The errors only change at the observed values: every threshold in (values[j], values[j + 1]] accepts the
    # impostors above values[j] and rejects the genuine rows at or below it
    lower = values[:-1]
    accepted = 1.0 - np.searchsorted(impostor, lower, side="right") / len(impostor)
    rejected = np.searchsorted(genuine, lower, side="right") / len(genuine)
    best = int(np.argmin(accepted + rejected))
    return float((values[best] + values[best + 1]) / 2.0)


def fit_place_matcher(references: np.ndarray, labels: np.ndarray, *, learned: bool, seed: int) -> NearestPlace:
    """
    A calibrated :class:`NearestPlace` for a memory's place vectors.

    On the raw vectors the threshold is :meth:`NearestPlace.calibrate`'s, over every row. A learned embedding pulls
    the rows of each place it trains on together, so their genuine similarities there say little about a photo in a
    new condition; the threshold is then **cross-fit**: a probe embedding is trained without a seeded share
    (:data:`PROBE_SHARE`) of the places seen more than once, and the threshold is calibrated on those places' rows
    in the probe's space (their genuine similarities are those of places it never trained on). The returned matcher
    compares in an embedding trained on every row, with that threshold.

    :param references: ``(n, d)`` the memory's place vectors
    :param labels: ``(n,)`` their place identities
    :param learned: Whether to compare in a :class:`PlaceEmbedding` fit on the references (default settings) rather
        than on the raw vectors
    :param seed: Seed of the embedding's training and of the probe places (unused on the raw vectors)
    :return: the matcher, its threshold calibrated on the references
    """
    references = _check_matrix("references", references)
    labels = _check_labels(labels, references)
    if not learned:
        return NearestPlace().calibrate(references, labels)
    embedding = PlaceEmbedding().fit(references, labels, seed=seed)
    places, counts = np.unique(labels, return_counts=True)
    repeated = places[counts >= 2]
    n_probe = max(1, round(PROBE_SHARE * len(repeated)))
    if len(repeated) - n_probe < 1:  # too few places seen twice to leave some out: calibrate on the training rows
        return NearestPlace(embedding=embedding).calibrate(references, labels)
    probe_places = np.random.default_rng(seed).choice(repeated, size=n_probe, replace=False)
    probed = np.isin(labels, probe_places)
    probe = PlaceEmbedding().fit(references[~probed], labels[~probed], seed=seed)
    calibrated = NearestPlace(embedding=probe).calibrate(references, labels, rows=probed)
    matcher = NearestPlace(calibrated.threshold, embedding)
    matcher.impostor_similarities = calibrated.impostor_similarities
    matcher.genuine_similarities = calibrated.genuine_similarities
    return matcher


# The references' condition: per-feature mean and spread of their views, and the farthest a reference's mean view lies
_Condition = tuple[np.ndarray, np.ndarray, float]


class AlignedNearestPlace:
    """
    Goal photos taken in other conditions than the agent's own views (night, passing cars), matched against the
    agent's own views without a label, and answered only where one place is clearly the nearest.

    **Condition.** A photo is of the references' own condition where the mean of its views lies, in the references'
    per-feature spread, no farther from the references' mean view than the farthest reference's does (a place never
    visited, pictured as the agent pictures, is such a photo). Farther, it is of another condition (at 22:30 every
    view is darker and its features' scale larger).

    **Alignment.** A photo of another condition is moved into the references' condition feature by feature: each
    feature standardised by the mean and spread of that condition's views -- the photo's own views and those of the
    other-condition photos among ``goal_pictures`` (the goal photos the memory was asked about, no place named) --
    then given the references' mean and spread (per-feature moment matching: the diagonal of CORAL, Sun, Feng &
    Saenko 2016, which one photo's four views already estimate; a full covariance needs many photos). A photo of the
    references' own condition is compared as it is.

    **Answer.** The reference of highest mean cosine similarity over the ``views`` blocks (a view in shadow pulls one
    block down, not the whole match), only where it is clearly nearer than the next place (Lowe's ratio test on the
    distance of the unit view blocks): at most ``own_ratio`` of it in the references' condition (there a near tie is
    a place not visited: the recogniser called the picture new), ``other_ratio`` in another (every distance is larger
    there and the margins narrow: 0.975 answered 95% of the campus's goals pictured at 22:30 with cars, none
    wrongly, and 30% of those of places never visited, wrongly); else ``-1``.

    **Candidates** (:meth:`candidates`). Where no place is clearly the nearest of a photo of another condition, the
    places whose nearest reference is within ``1 / candidate_ratio`` of the nearest one's distance, at most
    ``max_candidates`` of them, nearest first: a photo at night may show any of them (on the campus, every goal
    pictured at 19:30 or at 22:30 with cars that no place was clearly the nearest of was among its 4 candidates at
    0.95, one at the third rank). A route memory visits them and rules out each where the goal's episode goes on.
    A photo of the references' own condition has none (a near tie there is a place not visited).

    Unlike :class:`NearestPlace` with a learned :class:`PlaceEmbedding`, it needs no place seen in two conditions:
    the agent's own views (one condition) and the photos themselves suffice, which is all a fair memory has.

    :param views: Equal blocks of a picture (CampusNav: 4 views)
    :param own_ratio: The most the nearest place's distance may be of the next place's, in the references' condition
        (Lowe's 0.8)
    :param other_ratio: The same for a photo of another condition
    :param max_goal_pictures: The most recent other-condition goal photos that estimate the condition's moments
    :param candidate_ratio: The least the nearest place's distance may be of a candidate's (no more than
        ``other_ratio``: one candidate alone is a clear answer)
    :param max_candidates: The most places :meth:`candidates` names for one photo
    """

    def __init__(
        self,
        views: int = 1,
        own_ratio: float = 0.8,
        other_ratio: float = 0.975,
        max_goal_pictures: int = 32,
        candidate_ratio: float = 0.95,
        max_candidates: int = 4,
    ) -> None:
        if int(views) < 1:
            raise ValueError(f"AlignedNearestPlace: views must be at least 1, got {views}")
        for name, ratio in (("own_ratio", own_ratio), ("other_ratio", other_ratio)):
            if not 0.0 < float(ratio) <= 1.0:
                raise ValueError(f"AlignedNearestPlace: {name} is a ratio of distances in (0, 1], got {ratio}")
        if not 0.0 < float(candidate_ratio) <= float(other_ratio):
            raise ValueError(
                f"AlignedNearestPlace: candidate_ratio is a ratio of distances in (0, other_ratio={other_ratio}], got "
                f"{candidate_ratio}"
            )
        if int(max_goal_pictures) < 0:
            raise ValueError(f"AlignedNearestPlace: max_goal_pictures must be >= 0, got {max_goal_pictures}")
        if int(max_candidates) < 1:
            raise ValueError(f"AlignedNearestPlace: max_candidates must be >= 1, got {max_candidates}")
        self.views = int(views)
        self.own_ratio = float(own_ratio)
        self.other_ratio = float(other_ratio)
        self.max_goal_pictures = int(max_goal_pictures)
        self.candidate_ratio = float(candidate_ratio)
        self.max_candidates = int(max_candidates)

    def other_condition(self, pictures: np.ndarray, references: np.ndarray) -> np.ndarray:
        """``(m,)`` whether each picture is of another condition than the references (see the class docstring)."""
        return self._other(pictures, self._condition(references))

    def align(self, queries: np.ndarray, references: np.ndarray, goal_pictures: np.ndarray | None) -> np.ndarray:
        """The queries moved into the references' condition (those of the references' own condition as they are)."""
        return self._aligned(queries, goal_pictures, self._condition(references))[0]

    def _condition(self, references: np.ndarray) -> _Condition:
        """The references' per-feature mean and spread, and the farthest any reference's mean view lies from it."""
        views = _views_of(references, self.views)
        mean, spread = _moments(views)
        return mean, spread, float(_condition_shift(views, mean, spread).max())

    def _other(self, pictures: np.ndarray, condition: _Condition) -> np.ndarray:
        mean, spread, own_range = condition
        return _condition_shift(_views_of(pictures, self.views), mean, spread) > own_range

    def _aligned(
        self,
        queries: np.ndarray,
        goal_pictures: np.ndarray | None,
        condition: _Condition,
        other: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The queries moved into the references' condition, and which of them were of another one (``other``: those
        to move, instead of the condition test's)."""
        queries = np.asarray(queries, dtype=np.float64)
        other = self._other(queries, condition) if other is None else other
        if not other.any():
            return queries, other
        reference_mean, reference_spread, _ = condition
        sample = self._other_condition_sample(goal_pictures, condition)
        aligned = queries.copy()
        for row in np.flatnonzero(other):
            mean, spread = _moments(_views_of(np.concatenate([queries[row : row + 1], sample]), self.views))
            views = (_views_of(queries[row : row + 1], self.views) - mean) / spread
            aligned[row] = (views * reference_spread + reference_mean).reshape(-1)
        return aligned, other

    def _other_condition_sample(self, goal_pictures: np.ndarray | None, condition: _Condition) -> np.ndarray:
        """The most recent goal photos of another condition than the references' (``(0, d)``: none)."""
        if goal_pictures is None or not len(goal_pictures) or not self.max_goal_pictures:
            return np.zeros((0, condition[0].size * self.views))
        recent = np.asarray(goal_pictures, dtype=np.float64)[-self.max_goal_pictures :]
        return recent[self._other(recent, condition)]

    def similarities(self, queries: np.ndarray, references: np.ndarray) -> np.ndarray:
        """``(m, n)`` mean cosine similarity over the view blocks."""
        return _block_units(queries, self.views) @ _block_units(references, self.views).T / self.views

    def match(
        self, queries: np.ndarray, references: np.ndarray, labels: np.ndarray, goal_pictures: np.ndarray | None = None
    ) -> np.ndarray:
        """See :class:`PlaceMatcher`; ``goal_pictures`` are the goal photos asked about, oldest first."""
        return self._answers(queries, references, labels, goal_pictures, shortlist=False)[:, 0]

    def candidates(
        self, queries: np.ndarray, references: np.ndarray, labels: np.ndarray, goal_pictures: np.ndarray | None = None
    ) -> np.ndarray:
        """See :class:`CandidateMatcher` (and the class docstring): ``(m, max_candidates)`` rows, -1 padded."""
        return self._answers(queries, references, labels, goal_pictures, shortlist=True)

    def _answers(
        self,
        queries: np.ndarray,
        references: np.ndarray,
        labels: np.ndarray,
        goal_pictures: np.ndarray | None,
        shortlist: bool,
    ) -> np.ndarray:
        """``(m, k)`` rows (``k`` 1 without the ``shortlist`` of photos no place is clearly the nearest of)."""
        references = _check_matrix("references", references)
        queries = _check_matrix("queries", queries, references.shape[1])
        labels = _check_labels(labels, references)
        if references.shape[1] % self.views:
            raise ValueError(f"AlignedNearestPlace: {references.shape[1]} columns do not split into {self.views} views")
        width = self.max_candidates if shortlist else 1
        if len(references) == 0 or len(queries) == 0:
            return np.full((len(queries), width), NOT_IN_MEMORY, dtype=np.int64)
        if goal_pictures is not None:
            goal_pictures = _check_matrix("goal_pictures", goal_pictures, references.shape[1])
        condition = self._condition(references)
        aligned, other = self._aligned(queries, goal_pictures, condition)
        ratio = np.where(other, self.other_ratio, self.own_ratio)
        rows = self._nearest(aligned, references, labels, ratio, width, shortlisted=other)
        # A photo within the references' light overall (a place in shadow at noon, lit at night) that no place
        # matches clearly may be of the other asked photos' light: moved into the references' condition with their
        # moments, it is judged as they are (on the campus at night: 14 of 30 held-out splits below 0.95 of their
        # goals found, 3 with it; photos at noon of places never visited given a place: 1.8% -> 8%)
        retry = (rows[:, 0] == NOT_IN_MEMORY) & ~other
        if retry.any() and len(self._other_condition_sample(goal_pictures, condition)):
            moved, _ = self._aligned(queries[retry], goal_pictures, condition, other=np.ones(int(retry.sum()), bool))
            # A clear answer only: a near tie for a photo of the references' light is a place not visited
            ratio, none = np.full(len(moved), self.other_ratio), np.zeros(len(moved), dtype=bool)
            rows[retry] = self._nearest(moved, references, labels, ratio, width, shortlisted=none)
        return rows

    def _nearest(
        self,
        queries: np.ndarray,
        references: np.ndarray,
        labels: np.ndarray,
        ratio: np.ndarray,
        width: int,
        shortlisted: np.ndarray,
    ) -> np.ndarray:
        """
        ``(m, width)`` reference rows per query: its nearest row alone where that is nearer than the next place's by
        ``ratio``; else, for a ``shortlisted`` query, the nearest row of each place within ``1 / candidate_ratio`` of
        the nearest distance (at most ``width``, nearest first); -1 elsewhere.
        """
        # The distance of the pictures' unit view blocks (Lowe's ratio is of distances, not of 1 - similarities)
        distance = np.sqrt(np.maximum(1.0 - self.similarities(queries, references), 0.0))
        rows = np.full((len(queries), width), NOT_IN_MEMORY, dtype=np.int64)
        for query, row_distance in enumerate(distance):
            order = np.argsort(row_distance, kind="stable")
            _, first = np.unique(labels[order], return_index=True)
            # Each place's nearest row, the nearest place first (the rows of one place are no rival of each other)
            places = order[np.sort(first)]
            near = row_distance[places]
            if len(places) < 2:  # no rival place: no margin to judge
                continue
            if near[0] <= ratio[query] * near[1]:
                rows[query, 0] = places[0]
            elif shortlisted[query] and width > 1:
                close = places[near * self.candidate_ratio <= near[0]][:width]
                rows[query, : len(close)] = close
        return rows


def _views_of(pictures: np.ndarray, views: int) -> np.ndarray:
    """``(m, views, d / views)``: each picture's view blocks."""
    pictures = np.asarray(pictures, dtype=np.float64)
    return pictures.reshape(len(pictures), views, -1)


def _moments(views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per feature, the mean and spread of a set of views (a feature that never varies keeps its scale: spread 1)."""
    flat = views.reshape(-1, views.shape[2])
    spread = flat.std(axis=0)
    return flat.mean(axis=0), np.where(spread > NORM_EPS, spread, 1.0)


def _condition_shift(views: np.ndarray, mean: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """``(m,)`` how far each picture's mean view lies from ``mean``, in units of ``spread`` (root mean square)."""
    return np.sqrt((((views.mean(axis=1) - mean) / spread) ** 2).mean(axis=1))


def _block_units(vectors: np.ndarray, views: int) -> np.ndarray:
    """Each view block of each row divided by its norm."""
    blocks = np.asarray(vectors, dtype=np.float64).reshape(len(vectors), views, -1)
    return (blocks / np.maximum(np.linalg.norm(blocks, axis=2, keepdims=True), NORM_EPS)).reshape(len(vectors), -1)
