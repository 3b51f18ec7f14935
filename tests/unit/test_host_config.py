"""A robot's host configuration survives the JSON an agent process reads it from."""

import json
import math

from agent.core.params import RobotParams
from agent.runtime import HostConfig


def test_every_field_survives_to_json_and_back():
    config = HostConfig(
        robots=[3, 5],
        params=RobotParams(),
        display="lab",
        seed=7,
        arena=(-1.0, -2.0, 3.0, 4.0),
        obstacles=[[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]],
        batch_wait=0.07,
        lockstep=True,
        state_wait=2.5,
        pursue={3: 9},
        greet=[4],
        frames=True,
        steps=[0.0, 12.5],
        reach=1.5,
        swarm=40,
    )
    assert HostConfig.from_json(config.to_json()) == config


def test_keys_left_out_take_the_defaults():
    config = HostConfig.from_json(HostConfig(robots=[0], params=RobotParams()).to_json())
    assert config == HostConfig(robots=[0], params=RobotParams())
    assert config.reach == math.inf and config.arena is None and config.pursue == {}
    bare = HostConfig.from_json(json.dumps({"robots": [2], "params": RobotParams().to_dict()}))
    assert bare == HostConfig(robots=[2], params=RobotParams())


def test_params_a_step_used_still_compare_serialise_and_pickle_as_their_fields():
    """The control step keeps its compiled settings beside a RobotParams' fields (and a late robot's grown
    copy shares them); equality, to_json, copies and pickles see only the fields."""
    import copy
    import pickle

    from agent.core.step import settings_of

    params = RobotParams(v_pref=0.1)
    late = params.grown(0.01)
    assert settings_of(late) is settings_of(params)  # the radius is not in the settings
    assert params == RobotParams(v_pref=0.1) and hash(params) == hash(RobotParams(v_pref=0.1))
    for again in (pickle.loads(pickle.dumps(late)), copy.deepcopy(late)):
        assert again == late and again.radius == params.radius + 0.01
    config = HostConfig(robots=[1], params=late)
    assert HostConfig.from_json(config.to_json()) == config
