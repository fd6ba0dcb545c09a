"""Directly built PushAround inputs (issue 47, items 9 and 10): the PushScene, Movable and Fixed constructors
and plan_pushes refuse bad values with one TypeError / ValueError naming the argument, and a scene whose
pairwise geometry kernels would not fit in memory is refused before any work, naming the largest piece
that fits. No physics rollouts: every case fails before the search starts."""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from shapely.geometry import Polygon, box

from jaxplan.cli import main
from jaxplan.pusharound import (
    Fixed,
    Movable,
    PushScene,
    SearchConfig,
    build_wccg,
    check_feasible,
    check_memory,
    estimate_memory_bytes,
    plan_pushes,
    shapes,
)
from tests.pusharound.test_execution import TINY

NAN, INF = float("nan"), float("inf")
BOX = shapes.rectangle(0.4, 0.4)
L_SHAPE = Polygon([(0, 0), (1, 0), (1, 0.2), (0.2, 0.2), (0.2, 1), (0, 1)])   # not convex
AVAILABLE = "jaxplan.pusharound.budget.available_memory_bytes"


def _movable(**changes) -> Movable:
    args = {"name": "box", "pieces": BOX.pieces, "pose": (2.0, 0.5, 0.0), "mass": 6.0, "inertia": 0.16,
            "friction": 0.5, "shape": None, **changes}
    return Movable(**args)


def _scene(**changes) -> PushScene:
    args = {"workspace": (0.0, 0.0, 4.0, 3.0), "width": 0.8, "start": (1.0, 2.2), "goal": (3.0, 2.2),
            "fixed": (Fixed("wall", (box(1.9, 1.0, 2.1, 3.0),)),), "movables": (_movable(),),
            "robots": np.array([[0.5, 0.4], [0.5, 0.9]]), "robot_radius": 0.15, **changes}
    return PushScene(**args)


def test_the_good_scene_builds_and_is_normalised():
    scene = _scene(robots=[[0.5, 0.4]], movables=[_movable(mass=6)])
    assert isinstance(scene.movables, tuple) and isinstance(scene.movables[0].mass, float)
    assert scene.robots.shape == (1, 2) and scene.robots.dtype == np.float64
    assert _scene(robots=[]).robots.shape == (0, 2)
    check_feasible(scene)


@pytest.mark.parametrize("build, error, words", [
    # Movable
    (lambda: _movable(mass=-1.0), ValueError, "Movable('box').mass: must be > 0"),
    (lambda: _movable(mass=0), ValueError, "Movable('box').mass: must be > 0"),
    (lambda: _movable(mass=NAN), ValueError, "Movable('box').mass: must be finite"),
    (lambda: _movable(mass="6"), TypeError, "Movable('box').mass: expected a number"),
    (lambda: _movable(mass=True), TypeError, "Movable('box').mass: expected a number"),
    (lambda: _movable(inertia=0.0), ValueError, "Movable('box').inertia: must be > 0"),
    (lambda: _movable(inertia=INF), ValueError, "Movable('box').inertia: must be finite"),
    (lambda: _movable(friction=-0.5), ValueError, "Movable('box').friction: must be >= 0"),
    (lambda: _movable(pose=(NAN, 0.5, 0.0)), ValueError, "Movable('box').pose: expected [x, y, psi]"),
    (lambda: _movable(pose=(2.0, 0.5)), ValueError, "Movable('box').pose: expected [x, y, psi]"),
    (lambda: _movable(pose=(2.0, 0.5, 1e9)), ValueError, "Movable('box').pose: values must lie within"),
    (lambda: _movable(pose="2 0.5 0"), TypeError, "Movable('box').pose: expected [x, y, psi]"),
    (lambda: _movable(pose=np.zeros((1, 3))), ValueError, "Movable('box').pose: expected [x, y, psi]"),
    (lambda: _movable(pieces=()), ValueError, "Movable('box').pieces: empty"),
    (lambda: _movable(pieces=BOX.pieces[0]), TypeError, "Movable('box').pieces: expected a tuple"),
    (lambda: _movable(pieces=([[0, 0], [1, 0], [0, 1]],)), TypeError, "Movable('box').pieces[0]: expected a shapely"),
    (lambda: _movable(pieces=(L_SHAPE,)), ValueError, "Movable('box').pieces[0]: not convex"),
    (lambda: _movable(pieces=(Polygon([(0, 0), (1, 0), (NAN, 1)]),)), ValueError,
     "Movable('box').pieces[0]: coordinates must be finite"),
    (lambda: _movable(pieces=(box(0, 0, 1, 1), box(2, 0, 3, 1))), ValueError,
     "Movable('box').pieces: they do not form one connected body"),
    (lambda: _movable(name=5), TypeError, "Movable.name: expected a string"),
    (lambda: _movable(shape="cylinder"), TypeError, "Movable('box').shape: expected a dict"),
    # Fixed
    (lambda: Fixed("wall", box(0, 0, 1, 1)), TypeError, "Fixed('wall').pieces: expected a tuple"),
    (lambda: Fixed("wall", (Polygon([(0, 0), (1, 1), (1, 0), (0, 1)]),)), ValueError,
     "Fixed('wall').pieces[0]: self-intersecting polygon"),
    (lambda: Fixed("wall", (Polygon([(0, 0), (1, 1), (2, 2)]),)), ValueError, "Fixed('wall').pieces[0]:"),
    (lambda: Fixed(None, (box(0, 0, 1, 1),)), TypeError, "Fixed.name: expected a string"),
    # PushScene
    (lambda: _scene(width="0.8"), TypeError, "PushScene.width: expected a number"),
    (lambda: _scene(width=-0.8), ValueError, "PushScene.width: must be > 0"),
    (lambda: _scene(width=0), ValueError, "PushScene.width: must be > 0"),
    (lambda: _scene(width=NAN), ValueError, "PushScene.width: must be finite"),
    (lambda: _scene(width=None), TypeError, "PushScene.width: expected a number"),
    (lambda: _scene(robot_radius=0.0), ValueError, "PushScene.robot_radius: must be > 0"),
    (lambda: _scene(robot_radius=INF), ValueError, "PushScene.robot_radius: must be finite"),
    (lambda: _scene(start=(NAN, 2.2)), ValueError, "PushScene.start: expected [x, y]"),
    (lambda: _scene(goal=(3.0, 2.2, 0.0)), ValueError, "PushScene.goal: expected [x, y]"),
    (lambda: _scene(goal="3,2.2"), TypeError, "PushScene.goal: expected [x, y]"),
    (lambda: _scene(workspace=(0, 0, -4, 3)), ValueError, "PushScene.workspace: need x0 < x1"),
    (lambda: _scene(workspace=(0, 0, 4)), ValueError, "PushScene.workspace: expected [x0, y0, x1, y1]"),
    (lambda: _scene(workspace=(0, 0, 2000, 3)), ValueError, "PushScene.workspace: sides of at most"),
    (lambda: _scene(workspace=(0, 0, 4, INF)), ValueError, "PushScene.workspace: expected [x0, y0, x1, y1]"),
    (lambda: _scene(robots=np.zeros((2, 3))), ValueError, "PushScene.robots: expected shape (N, 2)"),
    (lambda: _scene(robots=np.zeros(4)), ValueError, "PushScene.robots: expected shape (N, 2)"),
    (lambda: _scene(robots=[[0.5, NAN]]), ValueError, "PushScene.robots[0]: expected finite"),
    (lambda: _scene(robots=[[0.5, 0.4], [0.5]]), ValueError, "PushScene.robots: expected an f[N, 2] array"),
    (lambda: _scene(robots=[["a", "b"]]), TypeError, "PushScene.robots: expected numbers"),
    (lambda: _scene(robots=np.ones((1, 2), bool)), TypeError, "PushScene.robots: expected numbers"),
    (lambda: _scene(movables=(BOX,)), TypeError, "PushScene.movables[0]: expected a Movable"),
    (lambda: _scene(fixed="wall"), TypeError, "PushScene.fixed: expected a tuple of Fixed"),
    # plan_pushes
    (lambda: plan_pushes(TINY, SearchConfig()), TypeError, "scene: expected a PushScene"),
    (lambda: plan_pushes(_scene(), "fast"), TypeError, "config: expected a SearchConfig"),
    (lambda: plan_pushes(_scene(), SearchConfig(time_limit_s=-1.0)), ValueError, "SearchConfig.time_limit_s"),
    (lambda: plan_pushes(_scene(), SearchConfig(time_limit_s="60")), ValueError, "SearchConfig.time_limit_s"),
    (lambda: plan_pushes(_scene(robots=[]), SearchConfig()), ValueError, "scene.robots: the search needs"),
])
@pytest.mark.filterwarnings("ignore::RuntimeWarning")   # shapely warns on a NaN vertex itself
def test_bad_input_is_refused_naming_the_argument(build, error, words):
    with pytest.raises(error) as err:
        build()
    message = str(err.value)
    assert type(err.value) is error and words in message and "\n" not in message, message


def test_rollout_poses_are_not_checked():
    """with_poses (a rollout's poses, which may be anything the physics produced) does not validate."""
    scene = _scene()
    assert math.isnan(scene.with_poses([[NAN, 0.5, 0.0]]).movables[0].pose[0])


# ---------------------------------------------------------------------------------------------------- memory

def _round_scene(n: int) -> PushScene:
    """One movable disk of radius 0.3 as an ``n``-gon in the open middle of the workspace, no fixed obstacle."""
    disk = shapes.cylinder(0.3, n=n)
    mov = Movable("disk", disk.pieces, (2.0, 1.5, 0.0), 5.0, shapes.polygon_inertia(disk.outline, 5.0))
    return _scene(fixed=(), movables=(mov,))


def _largest(message: str) -> int:
    found = re.search(r"the largest piece that fits has ([\d,]+) vertices", message)
    assert found, message
    return int(found.group(1).replace(",", ""))


def test_too_many_vertices_are_refused_naming_the_largest_count_that_fits():
    room = 10 ** 8
    scene = _round_scene(2048)
    est = estimate_memory_bytes(scene)
    assert est.v_max == 2048 and est.total_vertices == 2048 + 4 * 4 and est.bytes > room
    with pytest.raises(ValueError) as err:
        check_memory(scene, available=room)
    message = str(err.value)
    assert message.startswith("scene: its obstacles have 2,064 vertices in total") and "\n" not in message
    assert f"{est.bytes:,} bytes" in message and "more than the 100 MB of memory available" in message
    fit = _largest(message)
    assert 3 <= fit < 2048
    check_memory(_round_scene(fit), available=room)                  # the count named fits...
    with pytest.raises(ValueError):
        check_memory(_round_scene(fit + 1), available=room)          # ...and one more does not


def test_build_wccg_and_plan_pushes_refuse_before_any_work(monkeypatch):
    """The 100,000-vertex outline of the issue: refused in milliseconds (it would need about 10 TB)."""
    monkeypatch.setattr(AVAILABLE, lambda: 10 ** 9)
    scene = _round_scene(100_000)
    for call in (lambda: build_wccg(scene), lambda: plan_pushes(scene, SearchConfig()),
                 lambda: check_feasible(scene)):
        with pytest.raises(ValueError, match=r"^scene: its obstacles have 100,016 vertices in total.* TB "):
            call()
    monkeypatch.setattr(AVAILABLE, lambda: None)    # unknown memory: no check
    assert check_memory(_round_scene(12)).v_max == 12


def test_cli_refuses_a_scene_too_large_for_memory(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(AVAILABLE, lambda: 10 ** 9)
    disk = np.asarray(shapes.cylinder(0.2, n=2048).pieces[0].exterior.coords)[:-1]
    doc = {**TINY, "movables": [{**TINY["movables"][0], "pieces": [disk.round(9).tolist()]}]}
    scene_file = tmp_path / "round.json"
    scene_file.write_text(json.dumps(doc))
    with pytest.raises(SystemExit) as exc:
        main(["pusharound", "--scene", str(scene_file), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: --scene: {scene_file}: scene: its obstacles have "), lines
    assert "vertices in total" in lines[0] and "of memory available" in lines[0] and _largest(lines[0]) == 512
    assert not (tmp_path / "o").exists()
