"""Class vocabularies for ``lift3d label``: the COCO panoptic table, the ScanNet-style 21-class set, and the
mapping from a segmenter's classes (the *source* vocabulary) onto the scene's categories (the *target*).

A Mask2Former trained on COCO panoptic predicts 133 classes. A scene usually wants fewer, coarser ones
(``wall`` instead of ``wall-brick``, ``wall-stone``, ...). A :class:`ClassMapping` says which source classes
merge into which target category; source classes it does not mention become **void** (0).

``classes.json`` (``lift3d label --classes FILE``) lists the target categories; each names the source
classes merged into it, by name (case-insensitive) or by source category id::

    {"categories": [
      {"id": 1, "name": "wall",  "isthing": 0, "color": [174, 199, 232],
       "sources": ["wall-brick", "wall-stone", "wall-tile", "wall-wood", "wall-other-merged"]},
      {"id": 2, "name": "seat",  "isthing": 1, "sources": ["chair", 63]},
      {"id": 3, "name": "bed",   "isthing": 1}
    ]}

* ``id`` (integer ≥ 1, unique), ``name``, ``isthing`` (0/1) and ``color`` (optional ``[r, g, b]``) become
  the scene's ``categories``; ``isthing`` decides thing (one segment per object) or stuff (one segment per
  class and frame), whatever the source classes were.
* ``sources`` (optional, default ``[name]``): source class names, or integer source category ids (COCO
  panoptic ids 1-200 for COCO models; the model's ``id2label`` keys for other models; the files' own
  ``category_id`` values for imported predictions). A source may feed one target only. A name the
  segmenter does not know is an error (with close matches suggested), except a COCO panoptic class name:
  shared vocabularies list them all, and a segmenter without that class simply never predicts it.
* A bare JSON list of such objects is accepted too.

Built-in vocabularies (``--classes coco`` or ``--classes scannet21``): :data:`COCO_PANOPTIC_CATEGORIES` and
:data:`SCANNET21`.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence

import numpy as np

if TYPE_CHECKING:  # annotations only: the class tables must not need torch
    import torch

from lift3d.convert.predictions import parse_categories
from lift3d.data.categories import Category
from lift3d.errors import InputError
from lift3d.utils.files import read_json

# COCO panoptic's 133 categories (panopticapi's panoptic_coco_categories.json): id, isthing, colour, name.
# Row order is the contiguous class index Mask2Former and detectron2 use (0 = person ... 132 = rug-merged).
_COCO_TABLE = """
  1 1 220  20  60 person
  2 1 119  11  32 bicycle
  3 1   0   0 142 car
  4 1   0   0 230 motorcycle
  5 1 106   0 228 airplane
  6 1   0  60 100 bus
  7 1   0  80 100 train
  8 1   0   0  70 truck
  9 1   0   0 192 boat
 10 1 250 170  30 traffic light
 11 1 100 170  30 fire hydrant
 13 1 220 220   0 stop sign
 14 1 175 116 175 parking meter
 15 1 250   0  30 bench
 16 1 165  42  42 bird
 17 1 255  77 255 cat
 18 1   0 226 252 dog
 19 1 182 182 255 horse
 20 1   0  82   0 sheep
 21 1 120 166 157 cow
 22 1 110  76   0 elephant
 23 1 174  57 255 bear
 24 1 199 100   0 zebra
 25 1  72   0 118 giraffe
 27 1 255 179 240 backpack
 28 1   0 125  92 umbrella
 31 1 209   0 151 handbag
 32 1 188 208 182 tie
 33 1   0 220 176 suitcase
 34 1 255  99 164 frisbee
 35 1  92   0  73 skis
 36 1 133 129 255 snowboard
 37 1  78 180 255 sports ball
 38 1   0 228   0 kite
 39 1 174 255 243 baseball bat
 40 1  45  89 255 baseball glove
 41 1 134 134 103 skateboard
 42 1 145 148 174 surfboard
 43 1 255 208 186 tennis racket
 44 1 197 226 255 bottle
 46 1 171 134   1 wine glass
 47 1 109  63  54 cup
 48 1 207 138 255 fork
 49 1 151   0  95 knife
 50 1   9  80  61 spoon
 51 1  84 105  51 bowl
 52 1  74  65 105 banana
 53 1 166 196 102 apple
 54 1 208 195 210 sandwich
 55 1 255 109  65 orange
 56 1   0 143 149 broccoli
 57 1 179   0 194 carrot
 58 1 209  99 106 hot dog
 59 1   5 121   0 pizza
 60 1 227 255 205 donut
 61 1 147 186 208 cake
 62 1 153  69   1 chair
 63 1   3  95 161 couch
 64 1 163 255   0 potted plant
 65 1 119   0 170 bed
 67 1   0 182 199 dining table
 70 1   0 165 120 toilet
 72 1 183 130  88 tv
 73 1  95  32   0 laptop
 74 1 130 114 135 mouse
 75 1 110 129 133 remote
 76 1 166  74 118 keyboard
 77 1 219 142 185 cell phone
 78 1  79 210 114 microwave
 79 1 178  90  62 oven
 80 1  65  70  15 toaster
 81 1 127 167 115 sink
 82 1  59 105 106 refrigerator
 84 1 142 108  45 book
 85 1 196 172   0 clock
 86 1  95  54  80 vase
 87 1 128  76 255 scissors
 88 1 201  57   1 teddy bear
 89 1 246   0 122 hair drier
 90 1 191 162 208 toothbrush
 92 0 255 255 128 banner
 93 0 147 211 203 blanket
 95 0 150 100 100 bridge
100 0 168 171 172 cardboard
107 0 146 112 198 counter
109 0 210 170 100 curtain
112 0  92 136  89 door-stuff
118 0 218  88 184 floor-wood
119 0 241 129   0 flower
122 0 217  17 255 fruit
125 0 124  74 181 gravel
128 0  70  70  70 house
130 0 255 228 255 light
133 0 154 208   0 mirror-stuff
138 0 193   0  92 net
141 0  76  91 113 pillow
144 0 255 180 195 platform
145 0 106 154 176 playingfield
147 0 230 150 140 railroad
148 0  60 143 255 river
149 0 128  64 128 road
151 0  92  82  55 roof
154 0 254 212 124 sand
155 0  73  77 174 sea
156 0 255 160  98 shelf
159 0 255 255 255 snow
161 0 104  84 109 stairs
166 0 169 164 131 tent
168 0 225 199 255 towel
171 0 137  54  74 wall-brick
175 0 135 158 223 wall-stone
176 0   7 246 231 wall-tile
177 0 107 255 200 wall-wood
178 0  58  41 149 water-other
180 0 183 121 142 window-blind
181 0 255  73  97 window-other
184 0 107 142  35 tree-merged
185 0 190 153 153 fence-merged
186 0 146 139 141 ceiling-merged
187 0  70 130 180 sky-other-merged
188 0 134 199 156 cabinet-merged
189 0 209 226 140 table-merged
190 0  96  36 108 floor-other-merged
191 0  96  96  96 pavement-merged
192 0  64 170  64 mountain-merged
193 0 152 251 152 grass-merged
194 0 208 229 228 dirt-merged
195 0 206 186 171 paper-merged
196 0 152 161  64 food-other-merged
197 0 116 112   0 building-other-merged
198 0   0 114 143 rock-merged
199 0 102 102 156 wall-other-merged
200 0 250 141 255 rug-merged
"""


def _parse_coco_table(text: str) -> tuple[Category, ...]:
    out = []
    for line in text.strip().splitlines():
        cid, isthing, r, g, b, name = line.split(maxsplit=5)
        out.append(Category(int(cid), name, bool(int(isthing)), (int(r), int(g), int(b))))
    return tuple(out)


#: COCO panoptic categories in contiguous order (index ``i`` is Mask2Former's class ``i``).
COCO_PANOPTIC_CATEGORIES: tuple[Category, ...] = _parse_coco_table(_COCO_TABLE)


@dataclass(frozen=True)
class TargetClass:
    """One category of a target vocabulary and the source class names merged into it."""

    category: Category
    sources: tuple[str, ...]


def _target(cid: int, name: str, isthing: bool, color: tuple[int, int, int], *sources: str) -> TargetClass:
    return TargetClass(Category(cid, name, isthing, color), tuple(sources))


# The 21-class ScanNet-style vocabulary Panoptic Lifting evaluates on (its thing/stuff split: tables,
# cabinets, shelves and lamps are stuff there), expressed as merges of COCO panoptic classes. Everything a
# robot walks on is floor; small indoor objects are ``otherprop``; outdoor classes (sky, vehicles, animals,
# buildings, vegetation) are left out and so become void. Colours follow the ScanNet benchmark palette
# where it has the class.
SCANNET21: tuple[TargetClass, ...] = (
    _target(1, "wall", False, (174, 199, 232),
            "wall-brick", "wall-stone", "wall-tile", "wall-wood", "wall-other-merged"),
    _target(2, "floor", False, (152, 223, 138),
            "floor-wood", "floor-other-merged", "rug-merged", "pavement-merged", "road", "dirt-merged", "sand",
            "gravel", "platform", "playingfield", "railroad", "snow"),
    _target(3, "cabinet", False, (31, 119, 180), "cabinet-merged"),
    _target(4, "bed", True, (255, 187, 120), "bed"),
    _target(5, "chair", True, (188, 189, 34), "chair"),
    _target(6, "sofa", True, (140, 86, 75), "couch"),
    _target(7, "table", False, (255, 152, 150), "dining table", "table-merged"),
    _target(8, "door", False, (214, 39, 40), "door-stuff"),
    _target(9, "window", False, (197, 176, 213), "window-blind", "window-other"),
    _target(10, "counter", False, (23, 190, 207), "counter"),
    _target(11, "shelves", False, (148, 103, 189), "shelf"),
    _target(12, "curtain", False, (219, 219, 141), "curtain"),
    _target(13, "ceiling", False, (78, 71, 183), "ceiling-merged"),
    _target(14, "refrigerator", True, (255, 127, 14), "refrigerator"),
    _target(15, "television", True, (172, 114, 82), "tv"),
    _target(16, "person", True, (220, 20, 60), "person"),
    _target(17, "toilet", True, (44, 160, 44), "toilet"),
    _target(18, "sink", True, (112, 128, 144), "sink"),
    _target(19, "lamp", False, (255, 224, 32), "light"),
    _target(20, "bag", True, (0, 128, 128), "backpack", "handbag", "suitcase"),
    _target(21, "otherprop", False, (82, 84, 163),
            "book", "clock", "vase", "scissors", "teddy bear", "hair drier", "toothbrush", "laptop", "mouse",
            "remote", "keyboard", "cell phone", "microwave", "oven", "toaster", "bottle", "wine glass", "cup",
            "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange", "broccoli", "carrot",
            "hot dog", "pizza", "donut", "cake", "potted plant", "flower", "fruit", "food-other-merged",
            "pillow", "blanket", "towel", "mirror-stuff", "paper-merged", "cardboard", "banner", "umbrella",
            "tie", "frisbee", "skis", "snowboard", "sports ball", "kite", "baseball bat", "baseball glove",
            "skateboard", "surfboard", "tennis racket", "bench", "stairs", "net"),
)

#: Names accepted by ``--classes`` besides a path.
BUILTIN_VOCABULARIES = ("coco", "scannet21")


def builtin_classes_json(name: str) -> dict:
    """A built-in vocabulary written out in the ``classes.json`` format (a starting point to edit).

    Examples
    --------
    >>> d = builtin_classes_json("scannet21")
    >>> d["categories"][0]["name"], d["categories"][0]["sources"][:2]
    ('wall', ['wall-brick', 'wall-stone'])
    """
    if name == "scannet21":
        targets = SCANNET21
    elif name == "coco":
        targets = tuple(TargetClass(c, (c.name,)) for c in COCO_PANOPTIC_CATEGORIES)
    else:
        raise InputError("--classes", f"unknown built-in vocabulary {name!r} (have {', '.join(BUILTIN_VOCABULARIES)})")
    return {"categories": [{**t.category.to_json(), "sources": list(t.sources)} for t in targets]}


# --------------------------------------------------------------------------------------------- sources
@dataclass(frozen=True)
class SourceClass:
    """One class of the segmenter's own vocabulary.

    Attributes
    ----------
    index : int
        Position in the segmenter's output (the model's logit index, detectron2's contiguous id).
    id : int
        The id ``classes.json`` uses to name it (the COCO panoptic id for COCO classes).
    name : str
        Its name (matched case-insensitively).
    """

    index: int
    id: int
    name: str


def _key(name: str) -> str:
    return " ".join(str(name).casefold().split())


_COCO_BY_NAME = {_key(c.name): c for c in COCO_PANOPTIC_CATEGORIES}


def coco_sources() -> list[SourceClass]:
    """The 133 COCO panoptic classes as a source vocabulary (index = contiguous id, id = COCO id)."""
    return [SourceClass(i, c.id, c.name) for i, c in enumerate(COCO_PANOPTIC_CATEGORIES)]


def sources_from_labels(id2label: Mapping[int, str]) -> list[SourceClass]:
    """A model's ``config.id2label`` as a source vocabulary.

    When every name is a COCO panoptic class (the ``facebook/mask2former-*-coco-panoptic`` models), the ids
    are the COCO panoptic ids, so ``classes.json`` can refer to them by their official numbers; otherwise
    the ids are the model's own label indices.

    Examples
    --------
    >>> [s.id for s in sources_from_labels({0: "person", 1: "wall-other-merged"})]
    [1, 199]
    >>> [s.id for s in sources_from_labels({0: "road", 1: "sidewalk"})]
    [0, 1]
    """
    items = sorted((int(k), str(v)) for k, v in id2label.items())
    if [k for k, _ in items] != list(range(len(items))):
        raise InputError("--model", "config.id2label must number the classes 0..N-1 without gaps")
    if items and all(_key(n) in _COCO_BY_NAME for _, n in items):
        return [SourceClass(i, _COCO_BY_NAME[_key(n)].id, n) for i, n in items]
    return [SourceClass(i, i, n) for i, n in items]


def sources_from_categories(categories: Sequence[Category]) -> list[SourceClass]:
    """Categories read from a COCO categories JSON as a source vocabulary (id = the category id)."""
    return [SourceClass(i, c.id, c.name) for i, c in enumerate(categories)]


# --------------------------------------------------------------------------------------------- mapping
@dataclass
class ClassMapping:
    """Which source class feeds which target category.

    Attributes
    ----------
    sources : list of SourceClass
        The segmenter's vocabulary, in output order.
    categories : list of Category
        The target vocabulary (what the scene's ``categories`` become).
    target_of : np.ndarray
        ``int64 [S]``: for source ``s`` the index into ``categories``, or -1 (void).
    """

    sources: list[SourceClass]
    categories: list[Category]
    target_of: np.ndarray

    @property
    def num_targets(self) -> int:
        return len(self.categories)

    @property
    def unmapped(self) -> list[str]:
        """Names of the source classes that become void."""
        return [s.name for s, t in zip(self.sources, self.target_of.tolist()) if t < 0]

    @property
    def stuff_targets(self) -> set[int]:
        """Target indices of stuff categories (one segment per class and frame)."""
        return {k for k, c in enumerate(self.categories) if not c.isthing}

    def matrix(self) -> np.ndarray:
        """``float32 [S, K + 1]`` one-hot merge matrix; column ``K`` collects the unmapped classes.

        Multiplying source class probabilities by it sums the probabilities of merged classes, so a query
        split 0.3/0.3 between ``wall-brick`` and ``wall-stone`` is 0.6 ``wall``.
        """
        m = np.zeros((len(self.sources), self.num_targets + 1), np.float32)
        cols = np.where(self.target_of >= 0, self.target_of, self.num_targets)
        m[np.arange(len(self.sources)), cols] = 1.0
        return m

    def map_probabilities(self, probs: torch.Tensor) -> torch.Tensor:
        """Source class probabilities → target probabilities.

        Parameters
        ----------
        probs : torch.Tensor
            ``[..., S + 1]`` softmax over the source classes plus Mask2Former's trailing "no object".

        Returns
        -------
        torch.Tensor
            ``[..., K + 2]``: the ``K`` target categories, then "unmapped" (the summed probability of every
            source class that becomes void), then "no object". Rows still sum to 1.
        """
        import torch

        s = len(self.sources)
        if probs.shape[-1] != s + 1:
            raise ValueError(f"expected {s + 1} class probabilities (sources + no-object), got {probs.shape[-1]}")
        m = torch.as_tensor(self.matrix(), dtype=probs.dtype, device=probs.device)
        return torch.cat([probs[..., :s] @ m, probs[..., s:]], dim=-1)

    def source_index(self, source_id: int) -> int | None:
        """Position of the source class with id ``source_id`` (None when there is none)."""
        for s in self.sources:
            if s.id == source_id:
                return s.index
        return None

    def describe(self) -> str:
        """One line: how many source classes map onto how many categories, and how many become void."""
        things = sum(c.isthing for c in self.categories)
        n_void = len(self.unmapped)
        return (f"{len(self.sources)} source classes -> {self.num_targets} categories "
                f"({things} thing, {self.num_targets - things} stuff)"
                + (f", {n_void} unmapped (void)" if n_void else ""))

    def to_json(self) -> dict:
        """This mapping in the ``classes.json`` format (sources by name)."""
        cats = []
        for k, c in enumerate(self.categories):
            names = [s.name for s, t in zip(self.sources, self.target_of.tolist()) if t == k]
            cats.append({**c.to_json(), "sources": names})
        return {"categories": cats}


def identity_mapping(sources: Sequence[SourceClass]) -> ClassMapping:
    """Every source class is its own target category (the default for COCO panoptic models).

    Only COCO panoptic vocabularies can be used as they are: for any other the thing/stuff split is
    unknown, so a ``classes.json`` must say it.
    """
    cats = []
    for s in sources:
        coco = _COCO_BY_NAME.get(_key(s.name))
        if coco is None:
            raise InputError("--classes", f"the segmenter's classes are not COCO panoptic ones (e.g. {s.name!r}), so "
                                          "thing/stuff is unknown: pass --classes classes.json (see docs/label.md)")
        cats.append(coco)
    return ClassMapping(list(sources), cats, np.arange(len(sources), dtype=np.int64))


def mapping_from_targets(targets: Iterable[TargetClass], sources: Sequence[SourceClass],
                         where: str | Path = "--classes") -> ClassMapping:
    """Resolve target classes (with source names) against a source vocabulary."""
    raw = [{**t.category.to_json(), "sources": list(t.sources)} for t in targets]
    return parse_classes(raw, sources, where)


def parse_classes(raw: Any, sources: Sequence[SourceClass], where: str | Path) -> ClassMapping:
    """Build a :class:`ClassMapping` from parsed ``classes.json`` content.

    Parameters
    ----------
    raw : dict or list
        ``{"categories": [...]}`` or the list itself (module docstring).
    sources : sequence of SourceClass
        The segmenter's vocabulary.
    where : str or Path
        Named in errors (the file).

    Raises
    ------
    InputError
        Bad category fields, an unknown source class (with close matches), or a source claimed twice.

    Examples
    --------
    >>> m = parse_classes([{"id": 1, "name": "wall", "sources": ["wall-brick", 199]},
    ...                    {"id": 2, "name": "chair", "isthing": 1}], coco_sources(), "classes.json")
    >>> [m.categories[t].name if t >= 0 else None for t in m.target_of[[56, 109, 131, 0]]]
    ['chair', 'wall', 'wall', None]
    """
    if isinstance(raw, dict):
        raw = raw.get("categories")
    categories = parse_categories(raw, Path(str(where)))
    by_name = {}
    for s in sources:
        by_name.setdefault(_key(s.name), s)
    by_id = {s.id: s for s in sources}
    target_of = np.full(len(sources), -1, np.int64)
    for k, entry in enumerate(raw):
        refs = entry.get("sources", [categories[k].name])
        if isinstance(refs, (str, int)):
            refs = [refs]
        if not isinstance(refs, list) or not refs:
            raise InputError(where, f"categories[{k}].sources: expected a non-empty list of class names or ids")
        for ref in refs:
            if isinstance(ref, bool) or not isinstance(ref, (str, int)):
                raise InputError(where, f"categories[{k}].sources: {ref!r} is neither a class name nor an id")
            src = by_id.get(ref) if isinstance(ref, int) else by_name.get(_key(ref))
            if src is None and isinstance(ref, str) and _key(ref) in _COCO_BY_NAME:
                continue  # a COCO class this segmenter does not predict (shared vocabularies name them all)
            if src is None:
                raise InputError(where, f"categories[{k}] ({categories[k].name!r}): no source class "
                                        f"{ref!r}{_suggest(ref, sources)}")
            if target_of[src.index] >= 0 and target_of[src.index] != k:
                other = categories[int(target_of[src.index])].name
                raise InputError(where, f"categories[{k}] ({categories[k].name!r}): source class {src.name!r} "
                                        f"already feeds {other!r} (a source may feed one category only)")
            target_of[src.index] = k
    return ClassMapping(list(sources), categories, target_of)


def _suggest(ref: str | int, sources: Sequence[SourceClass]) -> str:
    if isinstance(ref, int):
        return " (no class has that id)"
    close = difflib.get_close_matches(_key(ref), [_key(s.name) for s in sources], n=3, cutoff=0.6)
    return f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""


def load_class_mapping(spec: str | Path | None, sources: Sequence[SourceClass]) -> ClassMapping:
    """The mapping ``--classes`` asks for.

    Parameters
    ----------
    spec : str, Path or None
        None or ``"coco"``: every source class as it is (COCO panoptic vocabularies only);
        ``"scannet21"``: the built-in :data:`SCANNET21` merge; anything else: a ``classes.json`` path.
    sources : sequence of SourceClass
        The segmenter's vocabulary.
    """
    if spec is None or str(spec) == "coco":
        return identity_mapping(sources)
    if str(spec) == "scannet21":
        return mapping_from_targets(SCANNET21, sources, "--classes scannet21")
    path = Path(spec)
    raw = read_json(path, missing=f"classes file not found (or use a built-in: {', '.join(BUILTIN_VOCABULARIES)})")
    return parse_classes(raw, sources, path)
