"""What a message may claim (transport.plausible) and which poses a robot drives on (agent.pose_trust)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.neighbour_table import NeighbourTable
from agent.pose_trust import CONFIRM, PoseTrust
from tests.conftest import run_scenes
from transport.codec import Goals, State, Tick
from transport.plausible import (
    AHEAD,
    DRIFT,
    FUTURE,
    INCONSISTENT,
    RESYNC,
    STALE,
    Clock,
    GoalSets,
    TickLine,
    stamp_agrees,
)

DT = 0.1


def test_a_stamp_must_be_its_ticks_start():
    assert stamp_agrees(1234, 123.4, DT)
    assert not stamp_agrees(1234 + 1000, 123.4, DT)  # the tick moved, the stamp intact
    assert not stamp_agrees(0, 1e-3, DT)


def test_one_tick_from_the_future_never_shuts_out_the_honest_ones():
    line = TickLine()
    assert line.admit(10, wall=0.0, now=10) is None
    assert line.admit(5000, wall=0.01, now=10) == FUTURE  # ahead of the receiver's clock
    assert line.admit(10 + AHEAD + 1, wall=0.02, now=10) == FUTURE
    assert line.admit(11, wall=0.1, now=11) is None  # the honest line goes on
    assert line.admit(11, wall=0.11, now=11) == STALE  # a duplicate
    assert line.admit(9, wall=0.12, now=11) == STALE  # older than what it holds


def test_real_time_a_tick_may_not_run_ahead_of_the_wall_clock():
    line = TickLine(period=DT)
    assert line.admit(100, wall=50.0) is None
    assert line.admit(100 + AHEAD + 3, wall=50.1) == FUTURE  # one period later: tick 101 at most, and AHEAD
    assert line.admit(101, wall=50.1) is None
    assert line.admit(120, wall=52.0) is None  # 2 s later (an outage): 20 ticks on is where the world is


def test_real_time_a_first_tick_that_came_late_does_not_hold_back_the_ticks_queued_behind_it():
    line = TickLine(period=DT)
    assert line.admit(100, wall=5.0) is None  # taken half a second late, with five more queued behind it
    assert [line.admit(100 + k, wall=5.0 + 0.001 * k) for k in range(1, 6)] == [None] * 5
    assert line.admit(106, wall=5.1) is None


def test_a_sender_that_restarts_is_heard_again_once_its_new_line_has_gone_on():
    line = TickLine(period=DT)
    for k in range(50):
        assert line.admit(500 + k, wall=k * DT) is None
    last = 49 * DT
    assert line.admit(0, wall=last + 0.1) == STALE  # a replayed old frame while the line speaks
    # the tracker restarted, counting from 0 again: heard once its new line has gone on for RESYNC
    restarted = [line.admit(k, wall=last + 0.1 + k * DT) for k in range(round(RESYNC / DT) + 1)]
    assert restarted[:-1] == [STALE] * (len(restarted) - 1) and restarted[-1] is None
    assert line.admit(len(restarted), wall=last + 0.2 + RESYNC) is None


def test_old_frames_copied_in_no_order_during_a_pause_never_take_the_line_back():
    """Lock-step: the world waits seconds for a late agent and the line is silent; copies of old
    frames (a faulty peer) arrive meanwhile. Taken as a restart, they made every honest tick after
    the pause look like the future, and the show stopped."""
    line = TickLine()
    for k in range(300):
        assert line.admit(k, wall=k * 0.01, now=k) is None
    rng = np.random.default_rng(1)
    for j in range(300):  # 3 s of pause, old copies at 100 a second
        assert line.admit(int(rng.integers(0, 300)), wall=3.0 + j * 0.01, now=299) == STALE
    assert line.admit(300, wall=6.1, now=300) is None


def test_a_clock_that_jumped_ahead_is_followed_once_it_goes_on():
    line = TickLine()  # as transport.plausible.Clock bounds it: a tick may not skip ahead of the newest
    assert line.admit(10, wall=0.0, now=None) is None
    jumped = [line.admit(1000 + k, wall=0.1 + k * DT, now=line.newest) for k in range(round(RESYNC / DT) + 1)]
    assert jumped[0] == FUTURE and jumped[-1] is None


def test_real_time_forged_clocks_each_a_little_ahead_never_carry_the_clock_past_the_wall():
    """The coordinator's clock picks the image a show is at: forged clocks, each AHEAD past the last
    taken, carried it to the show's end within a second when only the newest bounded them."""
    clock = Clock(period=DT)
    forged_taken = []
    for k in range(round(3 * RESYNC / DT)):  # 3 s: the world's tick k, and ten forged clocks between two ticks
        wall = k * DT
        assert clock.admit(Tick(k, k * DT, DT, 0), wall) is None or clock.newest > k
        for j in range(10):
            ahead = clock.newest + AHEAD
            if clock.admit(Tick(ahead, ahead * DT, DT, 0), wall + j * DT / 10) is None:
                forged_taken.append(ahead)
        # the wall clock, with RESYNC for a late first tick and DRIFT for a faster clock
        assert clock.newest <= k + 1 + (RESYNC + DRIFT * wall) / DT + AHEAD
    assert forged_taken  # each stays within AHEAD of the wall clock
    lockstep = Clock()  # no pace to bound it by: only the newest does
    lockstep.admit(Tick(0, 0.0, DT, 0), 0.0)
    for _ in range(10):
        lockstep.admit(Tick(lockstep.newest + AHEAD, (lockstep.newest + AHEAD) * DT, DT, 0), 0.0)
    assert lockstep.newest == 10 * AHEAD


def test_real_time_a_sender_whose_clock_runs_a_little_faster_is_heard_all_along():
    """Two machines' clocks differ: a tracker a half per cent fast is ahead by a second after 200 s."""
    line = TickLine(period=DT)
    assert all(line.admit(k, wall=k * DT * 0.995) is None for k in range(6000))  # 10 minutes


def test_real_time_a_new_line_of_ticks_faster_than_the_wall_clock_is_never_believed():
    line = TickLine(period=DT)
    assert line.admit(0, wall=0.0) is None
    fast = [line.admit(500 + 2 * k, wall=0.01 * k) for k in range(round(3 * RESYNC / 0.01))]  # 3 s, 20x the pace
    assert set(fast) == {FUTURE} and line.newest == 0
    assert line.admit(1, wall=3.0) is None  # the honest sender, late, is still heard


def test_a_receiver_that_starts_with_the_run_refuses_a_forged_first_epoch():
    """The world heard a faulty peer's copy of goal set 1 under epoch 6625 before the coordinator's
    own; it named 6625 in every clock tick, and every lock-step agent waited for it at every tick."""
    honest = Goals(1, 0, np.array([[0.5, 0.5], [0.6, 0.5]]), np.zeros((2, 3), np.uint8), np.arange(2))
    forged = dataclasses.replace(honest, epoch=6625)
    at_start = GoalSets((0, 0, 1, 1), newest=0)
    assert at_start.admit(forged, None) == FUTURE
    assert at_start.admit(honest, None) is None and at_start.newest == 1
    assert at_start.admit(forged, None) == FUTURE
    joining = GoalSets((0, 0, 1, 1))  # may join a run under way: takes the epoch it hears first
    assert joining.admit(dataclasses.replace(honest, epoch=40), None) is None
    assert joining.admit(forged, None) == FUTURE


def test_a_receiver_whose_link_came_back_takes_the_next_epoch_however_far_ahead():
    """The epochs published while a host's link was down never reached it, and the coordinator repeats only its
    newest: refused as too far ahead, it was refused for good, and the host never took a goal set again."""
    first = Goals(1, 0, np.array([[0.5, 0.5]]), np.zeros((1, 3), np.uint8), np.arange(1))
    newest = dataclasses.replace(first, epoch=5, positions=np.array([[0.6, 0.5]]))
    believed = GoalSets((0, 0, 1, 1), newest=0)
    assert believed.admit(first, None) is None and believed.admit(newest, None) == FUTURE
    believed.rejoin()
    assert believed.admit(newest, None) is None and believed.newest == 5
    assert believed.admit(dataclasses.replace(first, epoch=8), None) == FUTURE  # as far as AHEAD again, after it
    assert believed.admit(dataclasses.replace(first, epoch=6), None) == "replayed"  # what it heard, it still knows


def test_a_neighbour_state_from_the_future_is_refused_and_never_pushes_out_the_honest_ones():
    table = NeighbourTable(DT)
    table.advance(20)

    def state(tick: int, stamp: float | None = None) -> State:
        return State(7, tick, tick * DT if stamp is None else stamp, 0.3, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0, -1, 0)

    assert table.update(state(19)) is None
    for forged in (20 + AHEAD + 1, 9999, 123456):  # two of them kept as the newest used to evict the honest
        assert table.update(state(forged)) == FUTURE
    assert table.update(state(1000, stamp=19 * DT)) == FUTURE
    assert table.update(state(20, stamp=55.0)) == INCONSISTENT
    assert table.update(state(20)) is None
    assert [s.tick for s in table.latest_before(21)] == [20]
    table.advance(3)  # the clock went back: the tracker restarted
    assert len(table) == 0 and table.update(state(2)) is None


def test_a_pose_jumping_half_a_metre_for_one_tick_is_held_and_the_robot_resumes():
    trust = PoseTrust(v_max=0.13, dt=DT, slack=0.02)
    assert trust.judge(3, 10, 0.0, 0.0, 0.0) == (0.0, 0.0, 0.0)
    assert trust.judge(3, 11, 0.01, 0.0, 0.0) is not None  # 1 cm in a period: driven
    assert trust.judge(3, 12, 0.51, 0.0, 0.0) is None  # a swapped marker: brake
    assert trust.last(3) == (0.01, 0.0, 0.0)
    assert trust.judge(3, 13, 0.012, 0.0, 0.0) is not None  # the marker is back
    assert trust.held == 1


def test_a_robot_really_moved_is_taken_at_its_new_place_once_its_poses_agree():
    trust = PoseTrust(v_max=0.13, dt=DT, slack=0.02)
    trust.judge(0, 0, 0.0, 0.0, 0.0)
    place = [trust.judge(0, k, 0.6, 0.2, 1.0) for k in range(1, 1 + CONFIRM)]
    assert place[:-1] == [None] * (CONFIRM - 1) and place[-1] == (0.6, 0.2, 1.0)
    assert trust.judge(0, CONFIRM + 1, 0.61, 0.2, 1.0) is not None


def test_glitches_that_do_not_agree_with_each_other_are_never_believed():
    trust = PoseTrust(v_max=0.13, dt=DT, slack=0.02)
    trust.judge(0, 0, 0.0, 0.0, 0.0)
    for k in range(1, 40):
        angle = 2.4 * k  # never two places in a row within reach of each other
        assert trust.judge(0, k, 0.5 * math.cos(angle), 0.5 * math.sin(angle), 0.0) is None
    assert trust.last(0) == (0.0, 0.0, 0.0)


# Four robots abreast cross the display; the tracker reports robot 1 where robot 3 is for one tick.
GLITCH_SCENE = """
name = "glitch"
robots = 4
seed = 2
clock = "lockstep"
duration = 12.0
[robot]
kinematics = "{kinematics}"
[layout]
kind = "list"
poses = [[-0.375, -0.6, 1.5708], [-0.125, -0.6, 1.5708], [0.125, -0.6, 1.5708], [0.375, -0.6, 1.5708]]
[goals]
kind = "list"
positions = [[-0.375, 0.6], [-0.125, 0.6], [0.125, 0.6], [0.375, 0.6]]
{events}
"""
GLITCH_AT, GLITCH_ROBOT = 3.0, 1


@pytest.mark.slow
@pytest.mark.parametrize("kinematics", ["holonomic", "diffdrive"])
def test_a_swapped_marker_on_the_simulated_tracker_brakes_the_robot_without_contact_or_detour(tmp_path, kinematics):
    """The world's tracker reports one robot 0.5 m off for one tick, on top of another robot: the
    robot brakes for that tick, resumes as it was driving (a standoff turn would take it 10 mm off),
    and its path is the path of the same run without the glitch."""
    events = f'[[events]]\nkind = "tracker-glitch"\nt = {GLITCH_AT}\nrobot = {GLITCH_ROBOT}\noffset = [0.5, 0.0]'
    # the two at once: a lock-step run is the same run beside another, and its four agents wait on
    # each other's messages more than they compute
    runs = run_scenes(
        tmp_path,
        {
            "clean": (GLITCH_SCENE.format(kinematics=kinematics, events=""),),
            "glitched": (GLITCH_SCENE.format(kinematics=kinematics, events=events),),
        },
    )
    (m0, clean), (m1, glitched) = runs["clean"], runs["glitched"]
    assert m0["contacts"] == 0 and m1["contacts"] == 0
    assert m0["converged"] and m1["converged"]
    t, speed = glitched["t"], np.hypot(*glitched["velocity"][:, GLITCH_ROBOT].T)
    at = int(np.argmin(np.abs(t - GLITCH_AT)))
    assert speed[at - 1] > 0.02  # it was on its way ...
    assert speed[at] == 0.0 or speed[at + 1] == 0.0  # ... braked for the glitch ...
    assert speed[at + 3] > 0.02  # ... and drove on
    path = glitched["pose"][:, GLITCH_ROBOT, :2]
    reference = clean["pose"][:, GLITCH_ROBOT, :2]
    off_path = np.min(np.hypot(*(path[:, None, :] - reference[None, :, :]).transpose(2, 0, 1)), axis=1)
    assert off_path.max() < 0.007, f"a detour of {off_path.max():.4f} m"


def test_a_pose_off_the_arena_is_refused_and_a_far_position_has_a_cell():
    """A forged pose at 1e9 m was taken (at start-up with no check at all) and its cell overflowed the
    int64 key of the cells a host keeps: the agent died. A pose beyond ARENA_SLACK off the arena is
    refused; a position beyond any arena still has a cell (the outermost)."""
    from agent.core.params import EPUCK
    from agent.runtime import ARENA_SLACK, HostConfig, KeepCells, PoseIntake
    from transport.codec import Pose, Poses
    from transport.keys import cell_of, cells_of

    intake = PoseIntake(HostConfig([0], EPUCK, arena=(-1.0, -1.0, 1.0, 1.0)), None)
    at = lambda x, y: Pose(0, 5, 0.5, x, y, 0.0)  # noqa: E731
    assert intake.take(at(1e9, 1e9), lambda: 5) == "invalid"
    assert intake.take(at(1.0 + ARENA_SLACK + 0.01, 0.0), lambda: 5) == "invalid"
    assert intake.take(at(1.0 + ARENA_SLACK - 0.01, 0.0), lambda: 5) is None
    far = cell_of(1e300, -1e300, 0.6)
    assert far == tuple(cells_of([[1e300, -1e300]], 0.6)[0]) and far[0] > 0 > far[1]
    records = np.zeros(1, Poses.RECORD)
    records["x"], records["y"] = 1e30, 1e30
    assert not KeepCells({(0, 0)}, 0.6, frozenset()).mask(records).any()


def test_a_lockstep_pose_past_the_newest_clock_is_refused_and_the_honest_one_taken():
    """The world sends a tick's clock message before its poses, on the same link: a pose a tick or two past
    the newest clock was forged. Taken (the receiver's clock allowed AHEAD ticks), it made the honest poses
    until its tick look old: the robot answered no tick and the world waited for it, a minute a tick once
    the auction's messages kept it waiting."""
    from agent.core.params import EPUCK
    from agent.runtime import HostConfig, PoseIntake
    from transport.codec import Pose

    intake = PoseIntake(HostConfig([0], EPUCK), None)
    clock = lambda: 10  # noqa: E731 (the lock-step clock's newest tick)
    at = lambda tick, x: Pose(0, tick, tick * EPUCK.dt, x, 0.0, 0.0)  # noqa: E731
    assert intake.take(at(11, 0.9), clock) == FUTURE
    assert intake.take(at(12, 0.9), clock) == FUTURE
    assert intake.take(at(10, 0.1), clock) is None
    assert intake.pending[0] == at(10, 0.1)
    clock = lambda: 11  # noqa: E731
    assert intake.take(at(11, 0.11), clock) is None and intake.pending[0] == at(11, 0.11)


def test_a_second_pose_of_a_tick_at_another_place_makes_the_robot_brake_until_its_poses_agree():
    """A forged pose that came before the world's, for the same tick, was acted on and the honest one dropped as
    stale: the robot drove a tick behind itself. Two poses of one tick at different places leave which is true
    unknown: the second is refused as conflicting and the robot brakes for stale_after; a copy is no conflict."""
    from agent.core.params import EPUCK
    from agent.runtime import HostConfig, PoseIntake
    from transport.codec import Pose
    from transport.plausible import CONFLICTING

    intake = PoseIntake(HostConfig([0], EPUCK), None)
    clock = lambda: 11  # noqa: E731
    at = lambda tick, x: Pose(0, tick, tick * EPUCK.dt, x, 0.0, 0.0)  # noqa: E731
    assert intake.take(at(10, 0.10), clock) is None
    _, _, braking = intake.judged([intake.pending.pop(0)])
    assert not braking.any()
    assert intake.take(at(10, 0.10), clock) == STALE  # the same pose again: a copy, no doubt
    assert intake.take(at(11, 0.10), clock) is None  # the forged one, first: where the robot was
    _, _, braking = intake.judged([intake.pending.pop(0)])
    assert not braking.any()
    assert intake.take(at(11, 0.14), clock) == CONFLICTING  # the world's, where it drove
    doubt = intake.doubt_ticks
    assert doubt == math.ceil(EPUCK.stale_after / EPUCK.dt - 1e-9)
    for tick in range(12, 12 + doubt + 1):
        clock = lambda tick=tick: tick  # noqa: E731
        assert intake.take(at(tick, 0.14), clock) is None
        _, _, braking = intake.judged([intake.pending.pop(0)])
        assert braking.tolist() == [tick < 11 + doubt], tick
    # both before the step, with no command to say which is true: the robot brakes on the first
    assert intake.take(at(30, 0.2), lambda: 30) is None  # within reach of the last trusted pose
    assert intake.take(at(30, 0.25), lambda: 30) == CONFLICTING
    assert intake.pending[0] == at(30, 0.2)
    _, _, braking = intake.judged([intake.pending.pop(0)])
    assert braking.tolist() == [True]


def test_a_late_copy_of_a_pose_far_from_where_the_robot_drove_is_refused_without_braking():
    """A faulty peer's late copy of an older pose under a tick already taken made its robot brake, so the paper
    sequence under one missed an image. Of two poses of a tick, the tracker's is the one that copies no other
    tick's pose, else the one nearer where the robot's last command took it: a second that is not is refused
    alone; one that is makes the robot brake."""
    from agent.core.params import EPUCK
    from agent.runtime import HostConfig, PoseIntake
    from transport.codec import Command, Pose
    from transport.plausible import CONFLICTING

    intake = PoseIntake(HostConfig([0], EPUCK), None)
    at = lambda tick, x: Pose(0, tick, tick * EPUCK.dt, x, 0.0, 0.0)  # noqa: E731
    command = lambda tick: Command(0, tick, tick * EPUCK.dt, Command.WHEELS, 0.1, 0.1, 0, 0, 0)  # noqa: E731
    step = 0.1 * EPUCK.dt  # driving at 0.1 m/s
    assert intake.take(at(10, 0.0), lambda: 10) is None
    intake.judged([intake.pending.pop(0)])
    intake.drove(10, [[0.1, 0.0]], [command(10)])
    assert intake.take(at(11, step), lambda: 11) is None  # the tracker's
    _, _, braking = intake.judged([intake.pending.pop(0)])
    intake.drove(11, [[0.1, 0.0]], [command(11)])
    assert intake.take(at(11, 0.0), lambda: 11) == CONFLICTING  # a copy of tick 10's, late
    assert not intake.doubts(at(11, 0.0))
    assert intake.take(at(12, 2 * step), lambda: 12) is None
    _, _, braking = intake.judged([intake.pending.pop(0)])
    assert braking.tolist() == [False]
    # the copy first (taken), then the tracker's, nearer where the robot drove: it brakes
    intake.drove(12, [[0.1, 0.0]], [command(12)])
    assert intake.take(at(13, 2 * step), lambda: 13) is None
    intake.judged([intake.pending.pop(0)])
    assert intake.take(at(13, 3 * step), lambda: 13) == CONFLICTING
    assert intake.doubts(at(14, 3 * step))
    # a standing robot: a copy of its last pose lies exactly where its command (none) took it, yet is a copy
    intake = PoseIntake(HostConfig([0], EPUCK), None)
    for tick, x in ((20, 0.5), (21, 0.5002)):  # the tracker's noise: no two measurements alike
        assert intake.take(at(tick, x), lambda tick=tick: tick) is None
        intake.judged([intake.pending.pop(0)])
        intake.drove(tick, [[0.0, 0.0]], [command(tick)])
    assert intake.take(at(21, 0.5), lambda: 21) == CONFLICTING  # tick 20's, again under tick 21
    assert not intake.doubts(at(22, 0.5))


class _OneRobot:
    """agent.loop's seams for one holonomic robot with a goal 1 m ahead, alone: nobody heard, no auction."""

    def __init__(self) -> None:
        from agent.core.params import EPUCK
        from agent.core.policy import Memory

        self.params = dataclasses.replace(EPUCK, kinematics="holonomic")
        self.policy_memory, self.timing = Memory.new(1), {}

    def rows(self, ids):
        return slice(None)

    def goals(self, sensed):
        return np.array([[1.0, 0.0]]), np.array([[1, 0]])

    def neighbours(self, sensed):
        from agent.core.step import NeighbourStates

        return NeighbourStates.empty(1)

    def send(self, sensed, decision) -> None:
        pass

    active = False

    def step(self, sensed) -> None:
        pass

    def settled_beside(self) -> bool:
        return False


def test_a_robot_braked_on_a_glitch_drives_on_toward_its_goal_not_turning_as_from_a_standoff():
    """A brake stands the robot (its v_opt is zero), yet it is no standoff: once it trusts its pose again it heads
    for its goal, where a robot that starts from rest turns right first (agent.core.control's standoff turn)."""
    from agent.loop import Seams, Sensed, tick

    robot = _OneRobot()
    seams = Seams(robot, robot, None, seed=1)
    for k, braking in enumerate([False, False, False, True, False]):
        sensed = Sensed(np.array([0]), np.zeros((1, 2)), np.zeros(1), k, k * 0.1, robot.params, np.array([braking]))
        decision = tick(robot, sensed, seams)
        heading = math.degrees(math.atan2(*decision.step.pref_velocity[0][::-1]))
        if k == 0:
            assert heading == pytest.approx(-45.0, abs=0.1)  # from rest: the standoff turn
        if k == 3:
            assert np.all(robot.policy_memory.velocity == 0.0)  # braked: it stands
    assert heading == pytest.approx(0.0, abs=0.1)  # after the brake: straight for its goal
