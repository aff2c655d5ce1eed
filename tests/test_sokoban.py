"""Sokoban collections, LURD solutions, and `jc.env.SokobanMoves` replaying published
solutions of David W. Skinner's Microban (tests/data/sokoban/README.md) in the physics.

One jit compile in the module (`_replay`, cached); everything else is host code. The
grid rules are checked by a plain-Python Sokoban written here (`_grid_replay`), which
reads the maps on its own, not through `jaxchain.levels`.
"""

import doctest
import functools
import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import levels

DATA = pathlib.Path(__file__).parent / "data" / "sokoban"
MICROBAN = DATA / "microban.xsb"
REPLAYED = 30  # Microban levels replayed through the physics here (all: the benchmark).
STEP = {"l": (0, -1), "r": (0, 1), "d": (1, 0), "u": (-1, 0)}  # (row, column)


def _microban_maps():
  """The maps of microban.xsb: runs of lines that do not start with ';', split by blanks."""
  maps, run = [], []
  for line in MICROBAN.read_text().split("\n") + [""]:
    if line.strip() and not line.startswith(";"):
      run.append(line)
    elif run:
      maps.append(run)
      run = []
  return maps


def _solutions():
  text = (DATA / "microban_solutions.txt").read_text()
  lines = [line.strip() for line in text.split("\n")]
  numbers = [int(line[1:]) for line in lines if line.startswith("; ") and line[2:].isdigit()]
  moves = [line for line in lines if line and not line.startswith(";")]
  assert numbers == list(range(1, len(moves) + 1))
  return moves


def _grid_replay(rows, moves):
  """Plays `moves` (one letter each) on an XSB map by the rules: a move into a wall,
  or pushing a box into a wall or a box, does nothing. Returns the player's cell after
  each move, the final boxes and the goals, as world centres (x, y), y up."""
  height = len(rows)
  cells = {(r, c): ch for r, line in enumerate(rows) for c, ch in enumerate(line)}
  walls = {k for k, ch in cells.items() if ch == "#"}
  boxes = {k for k, ch in cells.items() if ch in "$*"}
  goals = {k for k, ch in cells.items() if ch in ".*+"}
  (player,) = [k for k, ch in cells.items() if ch in "@+"]
  world = lambda rc: (rc[1] + 0.5, height - rc[0] - 0.5)
  path = []
  for m in moves.lower():
    dr, dc = STEP[m]
    one, two = (player[0] + dr, player[1] + dc), (player[0] + 2 * dr, player[1] + 2 * dc)
    if one not in walls and not (one in boxes and (two in walls or two in boxes)):
      if one in boxes:
        boxes = (boxes - {one}) | {two}
      player = one
    path.append(world(player))
  return path, sorted(map(world, boxes)), sorted(map(world, goals))


# Collections and moves.


def test_a_collection_with_titles_comments_and_blank_lines():
  text = """Microcosmos (a test collection)
; by nobody

; 1 'First'

#####
#@$.#
#####

Title: not this one's
;  2
  ####
###  #
#@$ .#
#    #
######
Title: Second
Author: Someone
Comment:
a comment line: with a colon
#### not a map row, inside a comment block
Comment-End:


#######
#.$@$.#
#######
"""
  c = levels.parse_xsb_collection(text, name="micro")
  assert [lv.name for lv in c] == ["1 'First'", "Second", "micro 3"]
  # Walls merge into rectangles: 4, 5 and 4 of them.
  assert [lv.num_bodies for lv in c] == [4 + 3, 5 + 3, 4 + 5]
  assert [len(lv.tags["box"]) for lv in c] == [1, 1, 2]
  # Level 2's map is 5 rows high; its player is in row 2, column 1.
  assert c[1].pos[c[1].player].tolist() == [1.5, 2.5] and c[1].bounds == (0, 0, 6, 5)
  assert all(lv.gravity == (0.0, 0.0) for lv in c)
  with pytest.raises(ValueError, match=r"<xsb>: line 3, column 3: unknown character '\?'"):
    levels.parse_xsb_collection("; 1\n#####\n#@?.#\n#####\n")
  with pytest.raises(ValueError, match=r"no level"):
    levels.parse_xsb_collection("; only comments\nTitle: none\n")


def test_microban_loads_as_155_levels():
  c = levels.load_collection(MICROBAN)
  maps = _microban_maps()
  assert len(c) == len(maps) == 155
  assert [lv.name for lv in c[:2]] == ["1", "2"] and c[100].name == "101 'Lockdown'"
  for lv, rows in zip(c, maps):
    text = "".join(rows)
    assert len(lv.tags["box"]) == text.count("$") + text.count("*")
    assert len(lv.tags["goal"]) == text.count(".") + text.count("*") + text.count("+")
    assert lv.bounds[3] == len(rows)
  # Level 1: the player '@' in row 3 (of 7), column 2.
  assert c[0].pos[c[0].player].tolist() == [2.5, 7 - 3 - 0.5]
  with pytest.raises(ValueError, match=r"microban.xsb: holds 155 maps .*load_collection"):
    levels.load(MICROBAN)


def test_parse_moves_expands_run_lengths_and_groups():
  assert levels.parse_moves("dlu3rd") == "dlurrrd"
  assert levels.parse_moves("4drru2(3ruld)l") == "ddddrru" + "rrruld" * 2 + "l"
  assert levels.parse_moves("2(u2(lR))\n d") == "ulRlRulRlRd"
  for bad, match in (("rx", r"position 2: 'x' is not a move"), ("3", r"count 3 at the end"),
                     ("2(ul", r"unbalanced '\('"), ("ul)", r"position 3: unbalanced '\)'"),
                     ("2 r", r"position 2: a count \(2\) must come right before")):
    with pytest.raises(ValueError, match=match):
      levels.parse_moves(bad)


def test_every_published_microban_solution_solves_its_level_on_the_grid():
  maps, solutions = _microban_maps(), _solutions()
  assert len(solutions) == 155
  for k, (rows, moves) in enumerate(zip(maps, solutions), 1):
    _, boxes, goals = _grid_replay(rows, levels.parse_moves(moves))
    assert boxes == goals, f"level {k}"


# SokobanMoves in the physics.

# Every refusal of the push rule, then pushes that go: (action letters, map).
RULES = ["#######",
         "#     #",
         "#@$$ .#",
         "#  $ .#",
         "#   $.#",
         "#######"]
RULES_MOVES = "lrdrrrrdul"


@functools.cache
def _replay():
  """Replays the first REPLAYED Microban solutions and RULES_MOVES on RULES, every
  level in one jitted `jc.env.make_replay` (a vmapped scan of env.step_env): `(env,
  state, path)` with the player's position after every env step."""
  maps = _microban_maps()[:REPLAYED] + [RULES]
  moves = [levels.parse_moves(s) for s in _solutions()[:REPLAYED]] + [RULES_MOVES]
  task = jc.env.Task(name="microban", levels=levels.load_collection(MICROBAN)[:REPLAYED] +
                     [levels.parse_ascii("\n".join(RULES), gravity=(0.0, 0.0))],
                     actions=jc.env.SokobanMoves(), reward=jc.env.push_reward,
                     terminate=jc.env.sokoban_terminate,
                     params=jc.env.PushBoxParams(jitter=0.0, max_steps=10_000))
  env, params = jc.env.make(task, dt=1 / 64)
  actions = jc.env.sokoban_actions(moves)  # Padded with noops.
  state, path, _ = jax.jit(jc.env.make_replay(env, params))(np.arange(len(moves)), actions)
  return env, maps, moves, jax.device_get(state), np.asarray(path)


def test_sokoban_moves_replay_published_solutions_exactly():
  env, maps, moves, state, path = _replay()
  world = state.world
  box, goal = env.slots_of("box"), env.slots_of("goal")
  solved = 0
  for k, (rows, m) in enumerate(zip(maps, moves)):
    want_path, want_boxes, goals = _grid_replay(rows, m)
    # Every env step moved the player exactly where the grid rules put it (padding
    # noops after the solution keep it there), in float32 bits, not approximately.
    np.testing.assert_array_equal(path[k, :len(m)], np.asarray(want_path, np.float32))
    np.testing.assert_array_equal(path[k, len(m):], np.broadcast_to(want_path[-1],
                                                                    path[k, len(m):].shape))
    boxes = sorted(map(tuple, world.pos[k][box][world.active[k][box]].tolist()))
    assert boxes == want_boxes, f"level {k + 1}"
    if k < REPLAYED:
      assert boxes == goals, f"Microban {k + 1}: a box is off its goal"
      assert sorted(map(tuple, world.pos[k][goal][world.active[k][goal]].tolist())) == goals
      solved += 1
  assert solved == REPLAYED
  assert np.all(world.vel == 0) and np.all(world.status == 0)  # At rest; no FAST_BODY.
  assert np.asarray(world.sensed[:REPLAYED][:, goal] | ~world.active[:REPLAYED][:, goal]).all()


def test_sokoban_moves_refuse_blocked_pushes_in_the_world():
  env, maps, moves, state, path = _replay()
  # RULES from the player at row 2, column 1, i.e. (1.5, 3.5): l into a wall (refused);
  # r pushes a box into a box (refused); d, r walk; r, r push a box to (5.5, 2.5); r
  # would push it into the wall (refused); d would push the box below into the wall
  # (refused); u walks; l would push a box into a box (refused).
  want = [(1.5, 3.5), (1.5, 3.5), (1.5, 2.5), (2.5, 2.5), (3.5, 2.5), (4.5, 2.5), (4.5, 2.5),
          (4.5, 2.5), (4.5, 3.5), (4.5, 3.5)]
  assert [tuple(p) for p in path[-1, :len(RULES_MOVES)].tolist()] == want
  world = state.world
  box = env.slots_of("box")
  boxes = sorted(map(tuple, world.pos[-1][box][world.active[-1][box]].tolist()))
  assert boxes == [(2.5, 3.5), (3.5, 3.5), (4.5, 1.5), (5.5, 2.5)]
  assert _grid_replay(RULES, RULES_MOVES)[:2] == (want, boxes)


def test_replay_helpers():
  """`sokoban_actions` and `make_replay` are the one replay scan: this module and
  benchmarks/sokoban_replay.py both call them and write no scan of their own."""
  assert jc.env.sokoban_actions(["lurdLURD", "r"]).tolist() == [[1, 4, 2, 3, 1, 4, 2, 3],
                                                                 [2, 0, 0, 0, 0, 0, 0, 0]]
  assert jc.env.sokoban_actions([]).shape == (0, 0)
  with pytest.raises(ValueError, match=r"solution 1, position 2: '3' is not a move"):
    jc.env.sokoban_actions(["r", "u3r"])
  bench = (pathlib.Path(__file__).parents[1] / "benchmarks" / "sokoban_replay.py").read_text()
  for text in (bench, pathlib.Path(__file__).read_text()):
    assert "jc.env.make_replay(" in text and "jc.env.sokoban_actions(" in text
    assert "lax.scan" + "(" not in text and "ACTION" + " = " not in text
  finder = doctest.DocTestFinder()
  runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
  for test in finder.find(jc.env.sokoban_actions, "sokoban_actions", globs={}):
    runner.run(test)
  assert runner.tries > 0 and runner.failures == 0


def test_sokoban_moves_checks_its_setting():
  with pytest.raises(ValueError, match=r"repeat must be >= 2"):
    jc.env.SokobanMoves(repeat=1)
  with pytest.raises(ValueError, match=r"cell must be a number > 0"):
    jc.env.SokobanMoves(cell=0)


def test_without_the_controller_the_physics_breaks_the_push_rule():
  # Why SokobanMoves is a controller (docs/levels.md): the player driven one cell into a
  # box with a box behind it (no wall near) moves both boxes, and nobody lands on a cell.
  world = jc.World.create(pos=[[0.5, 0.5], [1.5, 0.5], [2.5, 0.5], [6.5, 0.5]],
                          half=[[0.4, 0.4], [0.45, 0.45], [0.45, 0.45], [0.5, 0.5]],
                          mass=[1.0, 1.0, 1.0, math.inf], gravity=(0.0, 0.0))
  config = jc.Config.for_world(world, dt=1 / 64)
  for k in range(5):  # Four quarter-cell steps at 16 units/s, then a stop.
    speed = 16.0 if k < 4 else 0.0
    world = jc.step(world, config, jnp.zeros((4, 2)).at[0, 0].set((speed - world.vel[0, 0]) * 64))
  assert world.pos[2, 0] > 2.5 + 0.25  # The second box moved: Sokoban forbids it.
  assert abs(float(world.pos[0, 0]) - 1.5) > 0.1  # The player is not on its cell.
  assert world.vel[1, 0] > 1.0  # The first box keeps sliding.


def test_sokoban_moves_with_dt_1_60_land_on_cells_within_rounding():
  rows, moves = _microban_maps()[0], levels.parse_moves(_solutions()[0])
  task = jc.env.Task(name="m1", levels=levels.load_collection(MICROBAN)[:1],
                     actions=jc.env.SokobanMoves(), reward=jc.env.push_reward,
                     terminate=jc.env.sokoban_terminate,
                     params=jc.env.PushBoxParams(jitter=0.0))
  env, params = jc.env.make(task)  # dt = 1/60: not a power of two.
  assert env.config.dt == 1 / 60
  state, path, info = jax.jit(jc.env.make_replay(env, params))(np.zeros(1, np.int32),
                                                              jc.env.sokoban_actions([moves]))
  state, path, success = jax.tree.map(lambda x: x[0], (state, path, info["success"]))
  want, boxes, goals = _grid_replay(rows, moves)
  np.testing.assert_allclose(np.asarray(path), want, rtol=0, atol=1e-5)
  box = env.slots_of("box")
  got = np.asarray(state.world.pos[box][np.asarray(state.world.active[box])])
  np.testing.assert_allclose(sorted(map(tuple, got.tolist())), goals, rtol=0, atol=1e-5)
  assert boxes == goals and bool(success[-1]) and not np.asarray(success[:-1]).any()
