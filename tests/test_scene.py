import numpy as np
import pytest

from simharness.errors import UserError
from simharness.scene import AgentType, Forecast, Scene, agent_types_from_labels
from simharness.sim.base import Frame, scene_from_frames


def test_agent_type_parse_and_footprints():
    assert AgentType.parse("rickshaw") is AgentType.RICKSHAW
    assert AgentType.parse(7) is AgentType.PEDESTRIAN
    assert all(length >= width > 0 for length, width in (t.footprint for t in AgentType))
    with pytest.raises(UserError, match="unknown agent type 'tuktuk'"):
        AgentType.parse("tuktuk")
    np.testing.assert_array_equal(agent_types_from_labels(["bus", "car", "bus"]), [1, 0, 1])


def test_scene_validates_shapes(scene):
    with pytest.raises(ValueError, match="heading"):
        scene.replace(heading=np.zeros((3, 9)))
    with pytest.raises(ValueError, match="unique"):
        scene.replace(agent_id=np.array(["a", "a", "b"]))
    assert scene.xy.dtype == np.float32 and scene.agent_type.dtype == np.int8


def test_slicing_keeps_frame_offset_and_ego(scene):
    part = scene.slice_frames(3, 7)
    assert part.num_frames == 4 and part.frame0 == 3
    np.testing.assert_allclose(part.times, scene.times[3:7])
    sub = scene.select_agents([2, 1])
    assert sub.ego == 1 and list(sub.agent_id) == ["a2", "a1"]
    assert scene.select_agents([0]).ego == -1


def test_velocity_matches_finite_difference(scene):
    vel = scene.velocity
    np.testing.assert_allclose(vel[1, 1:, 0], scene.speed[1, 1:], rtol=1e-4)
    assert np.all(vel[0, :2] == 0)  # invalid frames
    np.testing.assert_allclose(vel[0, 2, 0], scene.speed[0, 2], rtol=1e-4)  # first valid frame


def test_scene_from_frames_scatters_by_id():
    def frame(t, ids):
        n = len(ids)
        return Frame(t=t, agent_id=np.array(ids), agent_type=np.zeros(n, np.int8),
                     xy=np.full((n, 2), t, np.float32), heading=np.zeros(n), speed=np.ones(n),
                     length=np.full(n, 4.0), width=np.full(n, 2.0), ego=ids.index("e") if "e" in ids else -1)
    s = scene_from_frames([frame(0, ["b", "e"]), frame(1, ["e", "c"]), frame(2, ["b", "c"])], dt=1.0)
    assert list(s.agent_id) == ["b", "e", "c"] and s.ego == 1
    np.testing.assert_array_equal(s.valid, [[1, 0, 1], [1, 1, 0], [0, 1, 1]])
    assert s.xy[2, 2, 0] == 2


def test_forecast_checks_shapes():
    Forecast(agent_id=np.array(["a"]), mean=np.zeros((1, 5, 2)), dt=0.2, sigma_rho=np.zeros((1, 5, 3)))
    with pytest.raises(ValueError):
        Forecast(agent_id=np.array(["a"]), mean=np.zeros((1, 5, 2)), dt=0.2, sigma_rho=np.zeros((1, 4, 3)))


def test_empty_scene():
    assert Scene.empty(0.2, 5).num_agents == 0
