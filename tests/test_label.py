"""``lift3d label``: class mapping, TTA averaging, Mask2Former through transformers (a tiny random model
built in code, never downloaded), detectron2-style imports, and the scene files it writes.

Every test runs with ``HF_HUB_OFFLINE=1`` and with sockets blocked, so any attempt to reach the network
fails the test instead of downloading.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import socket
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lift3d.cli.main import main as cli_main
from lift3d.data.images import read_panoptic_png, read_unit_map, write_label_map
from lift3d.data.scene import Category, load_scene
from lift3d.errors import InputError
from lift3d.label import STAGING_DIR, Mask2FormerSettings, label_from_predictions, label_with_model
from lift3d.label.classes import (COCO_PANOPTIC_CATEGORIES, SCANNET21, builtin_classes_json, coco_sources,
                                  load_class_mapping, parse_classes, sources_from_labels)
from lift3d.label.predictions import convert_prediction, read_prediction
from lift3d.label.tta import (Augmentation, PassMaps, augmentations, mean_confidence, mean_probabilities,
                              pixel_confidence, relabel_segments, run_tta, segment_class_mass)

COCO_INDEX = {c.name: i for i, c in enumerate(COCO_PANOPTIC_CATEGORIES)}

# The tiny model's classes: COCO panoptic names (so they get COCO ids), one of them ("car") left unmapped.
MODEL_LABELS = ["wall-other-merged", "floor-wood", "ceiling-merged", "rug-merged", "window-other", "dining table",
                "chair", "cabinet-merged", "sports ball", "light", "potted plant", "vase", "airplane", "car"]

# classes.json onto the synthetic indoor scene's own categories (ids, names and thing/stuff as its GT).
SYNTH_CLASSES = {"categories": [
    {"id": 1, "name": "wall", "isthing": 0, "sources": ["wall-other-merged", "wall-brick"]},
    {"id": 2, "name": "floor", "isthing": 0, "sources": ["floor-wood", "floor-other-merged"]},
    {"id": 3, "name": "ceiling", "isthing": 0, "sources": ["ceiling-merged"]},
    {"id": 4, "name": "rug", "isthing": 0, "sources": ["rug-merged"]},
    {"id": 5, "name": "window", "isthing": 0, "sources": ["window-other", "window-blind"]},
    {"id": 6, "name": "table", "isthing": 1, "sources": ["dining table", "table-merged"]},
    {"id": 7, "name": "chair", "isthing": 1, "sources": ["chair"]},
    {"id": 8, "name": "cabinet", "isthing": 1, "sources": ["cabinet-merged"]},
    {"id": 9, "name": "ball", "isthing": 1, "sources": ["sports ball"]},
    {"id": 10, "name": "lamp", "isthing": 1, "sources": ["light"]},
    {"id": 11, "name": "plant", "isthing": 1, "sources": ["potted plant"]},
    {"id": 12, "name": "sculpture", "isthing": 1, "sources": ["teddy bear"]},
    {"id": 13, "name": "toy_plane", "isthing": 1, "sources": ["airplane"]},
    {"id": 14, "name": "sofa", "isthing": 1, "sources": ["couch"]},
    {"id": 15, "name": "shelf", "isthing": 1, "sources": ["shelf"]},
    {"id": 16, "name": "stool", "isthing": 1, "sources": ["bench"]},
    {"id": 17, "name": "book", "isthing": 1, "sources": ["book"]},
    {"id": 18, "name": "cup", "isthing": 1, "sources": ["cup"]},
    {"id": 19, "name": "vase", "isthing": 1, "sources": ["vase"]},
    {"id": 20, "name": "figurine", "isthing": 1, "sources": ["person"]},
    {"id": 21, "name": "box", "isthing": 1, "sources": ["cardboard"]},
]}


class NetworkAccess(RuntimeError):
    pass


@pytest.fixture(autouse=True)
def offline(monkeypatch):
    """No test may reach the network: HF offline mode plus sockets that refuse to connect."""
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("LIFT3D_NO_PROGRESS", "1")

    def refuse(*args, **kwargs):
        raise NetworkAccess(f"network access attempted: {args[1:] if len(args) > 1 else args}")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket.socket, "connect_ex", refuse)
    monkeypatch.setattr(socket, "getaddrinfo", refuse)


def test_network_guard_is_effective():
    with pytest.raises(NetworkAccess):
        socket.create_connection(("127.0.0.1", 9), timeout=0.1)


# --------------------------------------------------------------------------------------------- fixtures
def tiny_mask2former(labels=MODEL_LABELS, seed: int = 0):
    """A small random Mask2Former (Swin backbone of one block per stage, 12 queries), built in code."""
    from transformers import Mask2FormerConfig, Mask2FormerForUniversalSegmentation, SwinConfig

    torch.manual_seed(seed)
    backbone = SwinConfig(image_size=64, patch_size=4, embed_dim=16, depths=[1, 1, 1, 1], num_heads=[1, 1, 1, 1],
                          window_size=4, out_features=["stage1", "stage2", "stage3", "stage4"])
    config = Mask2FormerConfig(
        backbone_config=backbone, feature_size=32, mask_feature_size=32, hidden_dim=32, encoder_feedforward_dim=64,
        encoder_layers=1, decoder_layers=2, num_attention_heads=2, dim_feedforward=64, num_queries=12,
        id2label=dict(enumerate(labels)), label2id={n: i for i, n in enumerate(labels)},
    )
    model = Mask2FormerForUniversalSegmentation(config).eval()
    with torch.no_grad():
        # Random class heads are nearly uniform; sharpen them so queries pass the score threshold.
        model.class_predictor.weight.mul_(25.0)
    return model


def tiny_processor():
    """The image processor at a small inference size. transformers 5 has a torchvision and a PIL backend
    (the former falls back to the latter, with a warning, without torchvision); 4.x has one class."""
    import transformers

    cls = getattr(transformers, "Mask2FormerImageProcessorPil", None) or transformers.Mask2FormerImageProcessor
    return cls(size={"shortest_edge": 64, "longest_edge": 128})


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory) -> Path:
    """The tiny model saved as a local folder, the layout ``--model DIR`` reads."""
    d = tmp_path_factory.mktemp("tiny_m2f")
    tiny_mask2former().save_pretrained(d)
    tiny_processor().save_pretrained(d)
    return d


@pytest.fixture(scope="module")
def synth_template(tmp_path_factory) -> Path:
    from lift3d.synth import SynthOptions, make_scene

    root = tmp_path_factory.mktemp("synth") / "scene"
    make_scene(root, SynthOptions(n_views=4, width=64, height=64), progress=False)
    return root


@pytest.fixture
def scene(synth_template, tmp_path) -> Path:
    dst = tmp_path / "scene"
    shutil.copytree(synth_template, dst)
    return dst


@pytest.fixture
def classes_file(tmp_path) -> Path:
    p = tmp_path / "classes.json"
    p.write_text(json.dumps(SYNTH_CLASSES))
    return p


def tree_digest(root: Path, exclude: tuple[str, ...] = ()) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and not str(p.relative_to(root)).startswith(exclude)}


# --------------------------------------------------------------------------------------------- classes
def test_coco_panoptic_table():
    cats = COCO_PANOPTIC_CATEGORIES
    assert len(cats) == 133
    assert sum(c.isthing for c in cats) == 80 and sum(not c.isthing for c in cats) == 53
    ids = [c.id for c in cats]
    assert ids == sorted(ids) and len(set(ids)) == 133 and len({c.name for c in cats}) == 133
    # Things are COCO ids 1..90, stuff 92..200; contiguous index = position.
    assert all((c.id <= 90) == c.isthing for c in cats)
    assert (cats[0].id, cats[0].name) == (1, "person") and (cats[132].id, cats[132].name) == (200, "rug-merged")
    assert cats[COCO_INDEX["dining table"]].id == 67 and cats[COCO_INDEX["wall-other-merged"]].id == 199
    assert all(0 <= v <= 255 for c in cats for v in c.color)


def test_scannet21_vocabulary():
    m = load_class_mapping("scannet21", coco_sources())
    assert [c.id for c in m.categories] == list(range(1, 22))
    assert [c.name for c in m.categories][:9] == ["wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door",
                                                  "window"]
    assert {c.name for c in m.categories if c.isthing} == {"bed", "chair", "sofa", "refrigerator", "television",
                                                           "person", "toilet", "sink", "bag"}
    named = {m.categories[t].name for t in m.target_of[m.target_of >= 0]}
    assert len(named) == 21  # every class is fed by at least one COCO class
    target = {s.name: (m.categories[t].name if t >= 0 else None) for s, t in zip(m.sources, m.target_of)}
    assert target["couch"] == "sofa" and target["wall-brick"] == "wall" and target["dining table"] == "table"
    assert target["car"] is None and target["sky-other-merged"] is None  # outdoor classes become void
    assert sum(len(t.sources) for t in SCANNET21) == int((m.target_of >= 0).sum())  # no source lost or doubled


def test_builtin_classes_json_round_trips(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps(builtin_classes_json("scannet21")))
    from_file = load_class_mapping(p, coco_sources())
    builtin = load_class_mapping("scannet21", coco_sources())
    assert np.array_equal(from_file.target_of, builtin.target_of)
    assert from_file.categories == builtin.categories
    def canonical(d):  # sources in any order
        return [{**c, "sources": sorted(c["sources"])} for c in d["categories"]]

    assert canonical(from_file.to_json()) == canonical(builtin_classes_json("scannet21"))


def test_class_mapping_merges_probabilities():
    sources = sources_from_labels(dict(enumerate(["wall-brick", "wall-stone", "chair", "car"])))
    assert [s.id for s in sources] == [171, 175, 62, 3]  # COCO names get their COCO ids
    m = parse_classes({"categories": [{"id": 5, "name": "wall", "sources": ["Wall-Brick", 175]},
                                      {"id": 9, "name": "chair", "isthing": 1}]}, sources, "classes.json")
    assert m.target_of.tolist() == [0, 0, 1, -1] and m.unmapped == ["car"]
    probs = torch.tensor([[0.3, 0.3, 0.1, 0.2, 0.1],  # wall-brick, wall-stone, chair, car, no-object
                          [0.0, 0.1, 0.7, 0.0, 0.2]])
    out = m.map_probabilities(probs)  # wall, chair, unmapped, no-object
    assert torch.allclose(out, torch.tensor([[0.6, 0.1, 0.2, 0.1], [0.1, 0.7, 0.0, 0.2]]))
    assert torch.allclose(out.sum(-1), torch.ones(2))
    assert m.categories[1] == Category(9, "chair", True, m.categories[1].color)


@pytest.mark.parametrize("entries, message", [
    ([{"id": 1, "name": "wall", "sources": ["wall-brik"]}], "did you mean 'wall-brick'"),
    ([{"id": 1, "name": "wall", "sources": [12345]}], "no class has that id"),
    ([{"id": 1, "name": "a", "sources": ["chair"]}, {"id": 2, "name": "b", "sources": ["chair"]}],
     "already feeds 'a'"),
    ([{"id": 0, "name": "a", "sources": ["chair"]}], "must be >= 1"),
    ([{"id": 1, "name": "a", "sources": []}], "non-empty list"),
    ([{"id": 1, "name": "unicorn"}], "no source class 'unicorn'"),
])
def test_classes_json_errors(entries, message):
    with pytest.raises(InputError, match=message):
        parse_classes({"categories": entries}, coco_sources(), "classes.json")


def test_non_coco_model_needs_classes_json(tmp_path):
    sources = sources_from_labels({0: "road", 1: "sidewalk"})
    with pytest.raises(InputError, match="pass --classes"):
        load_class_mapping(None, sources)
    with pytest.raises(InputError, match="classes file not found"):
        load_class_mapping(tmp_path / "nope.json", sources)
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(InputError, match="not valid JSON"):
        load_class_mapping(tmp_path / "bad.json", sources)


# --------------------------------------------------------------------------------------------- TTA
def test_augmentations_put_identity_first():
    assert [str(a) for a in augmentations((0.5, 1.0, 2.0), flip=True)] == \
        ["x1", "x1 flip", "x0.5", "x0.5 flip", "x2", "x2 flip"]
    assert augmentations() == [Augmentation()]
    with pytest.raises(ValueError):
        augmentations((0.0,))


def colour_predictor(images, aug):
    """A flip-equivariant stand-in for a segmenter: each pixel's query is decided by its own colour only."""
    probs = torch.tensor([[0.1, 0.9, 0.0], [0.2, 0.1, 0.7], [0.0, 0.4, 0.6]])
    out = []
    for im in images:
        t = torch.as_tensor(im.astype(np.int64))
        winner = t[..., 0] % 3
        mask = (t[..., 1].float() + 1.0) / 257.0
        out.append(PassMaps(probs, torch.tensor([1, 2, 2]), probs[:, 1:].max(1).values, winner, mask))
    return out


def test_flip_tta_of_a_flip_equivariant_segmenter_equals_no_tta():
    image = np.random.default_rng(0).integers(0, 256, (9, 13, 3), dtype=np.uint8)  # not mirror-symmetric
    plain = run_tta([image], colour_predictor, augmentations())[0]
    flipped = run_tta([image], colour_predictor, augmentations(flip=True))[0]
    assert len(flipped) == 2
    assert torch.equal(flipped[1].winner, plain[0].winner)  # the flip pass was mapped back onto the image
    assert torch.allclose(mean_probabilities(flipped), mean_probabilities(plain))
    assert torch.allclose(mean_confidence(flipped), mean_confidence(plain))
    classes = plain[0].classes()
    assert torch.allclose(pixel_confidence(flipped, classes), pixel_confidence(plain, classes))


def hand_pass(winner, mask, probs, classes, scores) -> PassMaps:
    f64 = torch.float64
    return PassMaps(torch.tensor(probs, dtype=f64), torch.tensor(classes), torch.tensor(scores, dtype=f64),
                    torch.tensor(winner), torch.tensor(mask, dtype=f64))


def test_tta_averaging_math_on_hand_made_maps():
    # Classes: 0 void, 1 wall (stuff), 2 chair (thing). A 1x3 image, two passes.
    a = hand_pass([[0, 1, -1]], [[0.9, 0.5, 0.0]], [[0.1, 0.8, 0.1], [0.2, 0.0, 0.8]], [1, 2], [0.8, 0.8])
    b = hand_pass([[0, 0, 0]], [[0.7, 0.6, 0.4]], [[0.5, 0.25, 0.25]], [0], [0.5])
    p = mean_probabilities([a, b])
    expected = np.array([[(0.1 + 0.5) / 2, (0.2 + 0.5) / 2, (1.0 + 0.5) / 2],
                         [(0.8 + 0.25) / 2, (0.0 + 0.25) / 2, (0.0 + 0.25) / 2],
                         [(0.1 + 0.25) / 2, (0.8 + 0.25) / 2, (0.0 + 0.25) / 2]])[:, None, :]
    assert np.allclose(p.numpy(), expected)
    assert np.allclose(p.sum(0).numpy(), 1.0)
    assert np.allclose(mean_confidence([a, b]).numpy(), [[(0.8 * 0.9 + 0.5 * 0.7) / 2, (0.8 * 0.5 + 0.5 * 0.6) / 2,
                                                          (0.0 + 0.5 * 0.4) / 2]])
    # Per-segment sums without the dense maps agree with summing the dense maps.
    seg = torch.tensor([[0, 0, 1]])
    mass = segment_class_mass([a, b], seg, 2)
    assert np.allclose(mass.numpy(), [p[:, 0, :2].sum(1).numpy(), p[:, 0, 2].numpy()])
    # Pixel confidence counts a pass only where it agrees with the final class (b's class 0 never does).
    conf = pixel_confidence([a, b], torch.tensor([[1, 2, 2]]))
    assert np.allclose(conf.numpy(), [[0.9 / 2, 0.5 / 2, 0.0]])


def test_relabel_lets_the_passes_vote_and_fuses_stuff():
    # Identity pass: segment 1 = stuff class 1 (cols 0-1), segment 2 = thing class 2 (cols 2-3).
    # Two more passes say the thing pixels are class 1 (stuff): the vote makes segment 2 stuff class 1,
    # so it is fused into segment 1.
    seg = torch.tensor([[1, 1, 2, 2]])
    ident = hand_pass([[0, 0, 1, 1]], [[1.0] * 4], [[0.0, 0.9, 0.1], [0.0, 0.3, 0.7]], [1, 2], [0.9, 0.7])
    other = hand_pass([[0, 0, 0, 0]], [[0.8] * 4], [[0.0, 0.8, 0.2]], [1], [0.8])
    out_map, segs = relabel_segments(seg, {1: 1, 2: 2}, [ident, other, other], stuff_classes={1})
    assert out_map.tolist() == [[1, 1, 1, 1]]
    assert [(s.id, s.cls) for s in segs] == [(1, 1)]
    assert segs[0].score == pytest.approx(((0.9 + 0.8 + 0.8) / 3 * 2 + (0.3 + 0.8 + 0.8) / 3 * 2) / 4)
    # With the identity pass alone nothing changes: classes and scores are the segmenter's.
    out_map, segs = relabel_segments(seg, {1: 1, 2: 2}, [ident], stuff_classes={1})
    assert out_map.tolist() == [[1, 1, 2, 2]]
    assert [(s.id, s.cls, round(s.score, 6)) for s in segs] == [(1, 1, 0.9), (2, 2, 0.7)]


# --------------------------------------------------------------------------------------------- Mask2Former
def test_missing_transformers_is_a_one_line_error(monkeypatch):
    from lift3d.label.mask2former import load_mask2former

    monkeypatch.setitem(sys.modules, "transformers", None)  # makes `import transformers` raise ImportError
    with pytest.raises(InputError, match=r"pip install 'lift3d\[label\]'"):
        load_mask2former("facebook/mask2former-swin-large-coco-panoptic")


def test_weights_not_found_says_how_to_get_them(tmp_path):
    from lift3d.label.mask2former import load_mask2former

    with pytest.raises(InputError, match="huggingface-cli download facebook/mask2former-swin-large-coco-panoptic") as e:
        load_mask2former("facebook/mask2former-swin-large-coco-panoptic", cache_dir=tmp_path / "empty_cache")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="model folder not found"):
        load_mask2former(str(tmp_path / "no" / "such" / "model"))
    (tmp_path / "bert").mkdir()
    (tmp_path / "bert" / "config.json").write_text(json.dumps({"model_type": "bert"}))
    with pytest.raises(InputError, match="not Mask2Former"):
        load_mask2former(tmp_path / "bert")


@pytest.mark.parametrize("offline_env, hub_local_only", [("1", True), ("", False)])
def test_hf_hub_offline_sets_local_files_only(monkeypatch, model_dir, offline_env, hub_local_only):
    import transformers
    from lift3d.label.mask2former import load_mask2former_config

    seen = []

    def record(source, **kwargs):
        seen.append(kwargs["local_files_only"])
        raise OSError("stop here")

    monkeypatch.setenv("HF_HUB_OFFLINE", offline_env)
    monkeypatch.setattr(transformers.AutoConfig, "from_pretrained", record)
    for name in ("facebook/mask2former-swin-large-coco-panoptic", str(model_dir)):
        with pytest.raises(InputError, match="weights not found"):
            load_mask2former_config(name)
    assert seen == [hub_local_only, True]  # a local folder never needs the hub


def test_batches_of_different_image_sizes_are_cropped_to_each_image(model_dir):
    from lift3d.label.mask2former import Mask2FormerLabeler, load_mask2former

    model, processor = load_mask2former(model_dir)
    mapping = parse_classes(SYNTH_CLASSES, sources_from_labels(model.config.id2label), "classes.json")
    labeler = Mask2FormerLabeler(model, processor, mapping, threshold=0.5)
    rng = np.random.default_rng(0)
    wide = rng.integers(0, 256, (64, 128, 3), dtype=np.uint8)
    square = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    out = labeler.forward([wide, square])  # the square image is padded to the wide one's size
    (qh, qw), (sh, sw) = out[0].mask_logits.shape[-2:], out[1].mask_logits.shape[-2:]
    assert qw == 2 * qh and sw == sh == qh  # the padding is cut away: masks cover exactly their image
    preds = labeler.predict([wide, square])
    assert preds[0].panoptic.shape == (64, 128) and preds[1].panoptic.shape == (64, 64)


def test_loads_local_folder_offline(model_dir):
    from lift3d.label.mask2former import load_mask2former

    model, processor = load_mask2former(model_dir)
    assert model.config.model_type == "mask2former" and not model.training
    assert [model.config.id2label[i] for i in range(len(MODEL_LABELS))] == MODEL_LABELS
    assert hasattr(processor, "post_process_panoptic_segmentation")


def quadrant_queries(labeler, class_names):
    """Hand-made model output: query k covers quadrant k of an 8x8 image and is sure of class_names[k]."""
    from lift3d.label.mask2former import QueryOutput

    s = len(labeler.mapping.sources)
    logits = torch.full((4, s + 1), -20.0)
    for k, name in enumerate(class_names):
        logits[k, MODEL_LABELS.index(name)] = 20.0
    masks = torch.full((4, 8, 8), -20.0)
    masks[0, :4, :4] = masks[1, :4, 4:] = masks[2, 4:, :4] = masks[3, 4:, 4:] = 20.0
    return QueryOutput(logits, masks)


def test_panoptic_post_processing_in_target_space(tmp_path, classes_file):
    from lift3d.label.mask2former import Mask2FormerLabeler
    from lift3d.label.tta import relabel_segments as relabel

    model = tiny_mask2former()
    mapping = load_class_mapping(classes_file, sources_from_labels(model.config.id2label))
    labeler = Mask2FormerLabeler(model, tiny_processor(), mapping)
    # stuff, thing, the same stuff again, another thing: transformers' own stuff fusion would give the two
    # things the same segment id here; lift3d fuses stuff itself.
    q = quadrant_queries(labeler, ["wall-other-merged", "chair", "wall-other-merged", "car"])
    seg, classes = labeler.panoptic_segments(q, (8, 8))
    wall, chair = 1, 7  # target index + 1 (classes.json order)
    assert sorted(classes.values()) == [wall, wall, chair] and len(set(classes)) == 3
    assert (seg[4:, 4:] == 0).all()  # "car" is not in the vocabulary: void
    passes = [labeler.pass_maps(q, (8, 8))]
    fused, segs = relabel(seg, classes, passes, {t + 1 for t in mapping.stuff_targets})
    assert [s.cls for s in segs] == [wall, chair]
    assert len(torch.unique(fused[:, :4])) == 1 and fused[0, 0] != fused[0, 4]
    assert all(s.score == pytest.approx(1.0) for s in segs)
    conf = pixel_confidence(passes, torch.tensor([[wall] * 4 + [chair] * 4] * 4 + [[wall] * 4 + [0] * 4] * 4))
    assert torch.allclose(conf[:4], torch.ones(4, 8)) and (conf[4:, 4:] == 0).all()


def test_label_with_tiny_model_end_to_end(scene, model_dir, classes_file):
    gt_before = tree_digest(scene / "gt")
    images_before = tree_digest(scene / "images")
    meta_before = json.loads((scene / "transforms.json").read_text())
    rc = cli_main(["label", "--data", str(scene), "--model", str(model_dir), "--classes", str(classes_file),
                   "--threshold", "0.5", "--batch-size", "3", "--device", "cpu"])
    assert rc == 0
    s = load_scene(scene)
    s.validate()
    meta = json.loads((scene / "transforms.json").read_text())
    assert [(c["id"], c["name"], c["isthing"]) for c in meta["categories"]] == \
        [(c["id"], c["name"], c["isthing"]) for c in SYNTH_CLASSES["categories"]]
    for key in set(meta_before) - {"categories", "frames"}:
        assert meta[key] == meta_before[key]
    label_keys = ("panoptic_file_path", "confidence_file_path")
    for old, new in zip(meta_before["frames"], meta["frames"]):
        assert {k: v for k, v in new.items() if k not in label_keys} == \
            {k: v for k, v in old.items() if k not in label_keys}
        assert new["panoptic_file_path"].startswith("panoptic/")
        assert new["confidence_file_path"].startswith("confidence/")
    assert tree_digest(scene / "gt") == gt_before and tree_digest(scene / "images") == images_before
    assert not (scene / STAGING_DIR).exists()
    coco = json.loads((scene / "panoptic.json").read_text())
    n_segments, used = 0, set()
    for f, ann in zip(s.frames, coco["annotations"]):
        seg = read_panoptic_png(f.panoptic_path)
        assert seg.shape == (64, 64)
        ids = {d["id"] for d in ann["segments_info"]}
        assert set(np.unique(seg).tolist()) - {0} == ids
        for d in ann["segments_info"]:
            assert 0.0 <= d["score"] <= 1.0 and d["area"] == int((seg == d["id"]).sum())
            used.add(d["category_id"])
        stuff = [d["category_id"] for d in ann["segments_info"] if not s.category_by_id[d["category_id"]].isthing]
        assert len(stuff) == len(set(stuff))  # one segment per stuff class
        conf = read_unit_map(f.confidence_path)
        assert conf.shape == (64, 64) and conf.min() >= 0 and conf.max() <= 1
        assert (conf[seg == 0] == 0).all() and conf[seg > 0].max(initial=1.0) > 0  # a frame may get no segment
        n_segments += len(ids)
    assert n_segments > 0 and used <= {c["id"] for c in SYNTH_CLASSES["categories"]}

    # Again with TTA, replacing the labels; probabilities in Panoptic Lifting's npz layout.
    rc = cli_main(["label", "--data", str(scene), "--model", str(model_dir), "--classes", str(classes_file),
                   "--threshold", "0.5", "--tta", "--tta-scales", "1,1.5", "--save-probabilities"])
    assert rc == 0
    s = load_scene(scene)
    s.validate()
    z = np.load(scene / "probabilities" / f"{s.frames[0].name}.npz")
    assert z["probability"].shape == (64, 64, len(SYNTH_CLASSES["categories"]) + 1) and z["confidence"].shape == (64, 64)
    assert np.allclose(z["probability"].astype(np.float32).sum(-1), 1.0, atol=1e-2)
    assert list(z["class_names"][:3]) == ["void", "wall", "floor"]
    assert tree_digest(scene / "gt") == gt_before


def test_label_refuses_a_vocabulary_that_breaks_the_ground_truth(scene, model_dir, capsys):
    before = tree_digest(scene)
    rc = cli_main(["label", "--data", str(scene), "--model", str(model_dir)])  # COCO ids vs the scene's
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "gt/panoptic.json" in err and "--classes" in err
    assert tree_digest(scene) == before


def test_label_scene_without_ground_truth_uses_coco(scene, model_dir):
    shutil.rmtree(scene / "gt")
    meta = json.loads((scene / "transforms.json").read_text())
    for f in meta["frames"]:
        f.pop("gt_panoptic_file_path", None)
        f.pop("gt_depth_file_path", None)
    (scene / "transforms.json").write_text(json.dumps(meta))
    report = label_with_model(scene, model_dir, Mask2FormerSettings(threshold=0.5), progress=False)
    s = load_scene(scene)
    s.validate()
    assert [c.name for c in s.categories] == MODEL_LABELS
    assert [c.id for c in s.categories] == [COCO_PANOPTIC_CATEGORIES[COCO_INDEX[n]].id for n in MODEL_LABELS]
    assert report["frames"] == 4 and report["classes"].startswith("14 source classes -> 14 categories")


def test_failure_midway_leaves_the_scene_untouched(scene, model_dir, classes_file):
    from lift3d.label.mask2former import Mask2FormerLabeler

    model = tiny_mask2former()
    labeler = Mask2FormerLabeler(model, tiny_processor(), load_class_mapping(
        classes_file, sources_from_labels(model.config.id2label)), threshold=0.5)
    calls = []
    real_predict = labeler.predict

    def flaky(images, augs, keep_probabilities=False):
        calls.append(len(images))
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real_predict(images, augs, keep_probabilities)

    labeler.predict = flaky
    before = tree_digest(scene)
    with pytest.raises(KeyboardInterrupt):
        label_with_model(scene, "unused", labeler=labeler, progress=False)
    assert calls == [1, 1, 1]
    assert tree_digest(scene) == before and not (scene / STAGING_DIR).exists()


# --------------------------------------------------------------------------------------------- predictions
def test_detectron2_predictions_round_trip(scene, classes_file, tmp_path):
    s = load_scene(scene)
    cats = s.category_by_id
    source_of = {c["id"]: COCO_INDEX[c["sources"][0]] for c in SYNTH_CLASSES["categories"]}
    pred_dir = tmp_path / "preds"
    pred_dir.mkdir()
    expected = []
    rng = np.random.default_rng(1)
    for i, f in enumerate(s.frames):
        gt = s.gt_labels(i)
        seg = gt.segment.astype(np.int64)
        infos, exp_scores = [], {}
        for sid in np.unique(seg[seg > 0]).tolist():
            cid = int(gt.semantic[seg == sid][0])
            score = float(rng.uniform(0.3, 1.0))
            infos.append({"id": sid, "category_id": source_of[cid], "isthing": cats[cid].isthing, "score": score})
            exp_scores[sid] = score
        # A stuff segment (wall, GT id 1) split in two: fused again on import, with the area-weighted score ...
        assert (seg == 1).sum() > 100
        split_id = int(seg.max()) + 1
        rows = np.nonzero((seg == 1).any(1))[0]
        lower = (seg == 1) & (np.arange(64)[:, None] > rows.mean())
        seg[lower] = split_id
        infos.append({"id": split_id, "category_id": source_of[1], "isthing": False, "score": 0.2})
        # ... and a segment of a class the vocabulary leaves out ("car"), which becomes void.
        seg[:6, :6] = split_id + 1
        infos.append({"id": split_id + 1, "category_id": COCO_INDEX["car"], "isthing": True, "score": 0.9})
        a_up, a_low = int((seg == 1).sum()), int((seg == split_id).sum())
        exp_scores[1] = (exp_scores[1] * a_up + 0.2 * a_low) / (a_up + a_low)
        semantic = np.where(seg == split_id + 1, 0, gt.semantic)
        exp_seg = np.where(seg == split_id, 1, np.where(seg == split_id + 1, 0, seg))
        expected.append((semantic, exp_seg, exp_scores))
        if i % 2 == 0:
            np.savez(pred_dir / f"{f.name}.npz", panoptic_seg=seg.astype(np.int32), segments_info=json.dumps(infos))
        elif i == 1:
            torch.save((torch.from_numpy(seg.astype(np.int32)), infos), pred_dir / f"{f.name}.pt")
        else:
            torch.save({"panoptic_seg": torch.from_numpy(seg), "segments_info": infos,
                        "confidence": torch.full((64, 64), 0.25)}, pred_dir / f"{f.name}.pth")
    # Old labels came with confidence maps: they describe the old labels and must not survive the import.
    meta = json.loads((scene / "transforms.json").read_text())
    for f in meta["frames"]:
        f["confidence_file_path"] = "old_confidence.png"
    write_label_map(scene / "old_confidence.png", np.full((64, 64), 65535))
    (scene / "transforms.json").write_text(json.dumps(meta))
    assert load_scene(scene).frames[0].confidence_path is not None
    rc = cli_main(["label", "--data", str(scene), "--from-predictions", str(pred_dir), "--classes", str(classes_file)])
    assert rc == 0
    s2 = load_scene(scene)
    s2.validate()
    for i, (semantic, exp_seg, exp_scores) in enumerate(expected):
        lab = s2.pseudo_labels(i)
        assert np.array_equal(lab.semantic, semantic)
        assert np.array_equal(lab.segment, exp_seg)
        segs = s2.frames[i].segments
        assert set(segs) == set(np.unique(exp_seg).tolist()) - {0}
        for sid, seg_info in segs.items():
            assert seg_info.score == pytest.approx(exp_scores[sid])
        things = np.isin(semantic, s2.thing_ids)
        assert np.array_equal(lab.instance, np.where(things, exp_seg, 0))
        assert (s2.frames[i].confidence_path is not None) == (i == 3)
        if i == 3:
            assert np.allclose(lab.confidence, np.where(exp_seg > 0, 0.25, 0) * np.vectorize(
                lambda v: exp_scores.get(v, 0.0))(exp_seg), atol=1e-4)


def test_prediction_file_errors(scene, tmp_path, classes_file):
    s = load_scene(scene)
    pred_dir = tmp_path / "p"
    pred_dir.mkdir()
    before = tree_digest(scene)
    with pytest.raises(InputError, match=f"no prediction for frame '{s.frames[0].name}'"):
        label_from_predictions(scene, pred_dir, classes=classes_file, progress=False)
    assert tree_digest(scene) == before

    seg = np.zeros((64, 64), np.int32)
    seg[:8] = 3
    bad = pred_dir / "bad.npz"
    np.savez(bad, panoptic_seg=seg, segments_info=np.array([{"id": 3, "category_id": 0}], dtype=object))
    with pytest.raises(InputError, match="JSON string"):
        read_prediction(bad)
    np.savez(bad, panoptic_seg=seg, segments_info=json.dumps([{"id": 4, "category_id": 0}]))
    with pytest.raises(InputError, match=r"segment ids \[3\] are in panoptic_seg but not in segments_info"):
        read_prediction(bad)
    np.savez(bad, panoptic_seg=seg, segments_info=json.dumps([{"id": 3, "category_id": 0, "score": 1.5}]))
    with pytest.raises(InputError, match="not in"):
        read_prediction(bad)
    torch.save({"something": 1}, pred_dir / "odd.pt")
    with pytest.raises(InputError, match="panoptic_seg"):
        read_prediction(pred_dir / "odd.pt")


def test_prediction_at_lower_resolution_is_resized(tmp_path):
    seg = np.zeros((32, 48), np.int32)
    seg[:, 24:] = 7
    p = tmp_path / "f.npz"
    np.savez(p, panoptic_seg=seg, segments_info=json.dumps([{"id": 7, "category_id": COCO_INDEX["chair"],
                                                               "score": 0.5}]))
    mapping = load_class_mapping(None, coco_sources())
    out, segments, conf = convert_prediction(read_prediction(p), mapping, (64, 96), {i: i for i in range(133)})
    assert out.shape == (64, 96) and (out[:, 48:] == 7).all() and (out[:, :48] == 0).all()
    assert [(sg.id, sg.category_id, sg.score) for sg in segments] == [(7, 62, 0.5)]
    with pytest.raises(InputError, match="another aspect ratio"):
        convert_prediction(read_prediction(p), mapping, (64, 64), {i: i for i in range(133)})
