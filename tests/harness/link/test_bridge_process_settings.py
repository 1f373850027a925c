"""A bridge served inside another program (the play world, a test) leaves the process as it found it: the thread
switch interval it lowers and the objects it freezes for the garbage collector are restored when it closes."""
import gc
import sys

from harness.link.bridge_sim import BridgeOptions, SimBridge
from harness.sim.robot.simulated_wam import SimulatedWam, SimWamOptions
from robot_models import WamKinematics, load_robot_config


def test_serving_restores_the_switch_interval_and_the_gc_freeze():
    kin = WamKinematics.from_config(load_robot_config(None))
    bridge = SimBridge(SimulatedWam(kin, SimWamOptions(), seed=0),
                       BridgeOptions(bind="tcp://127.0.0.1:*", state_bind="tcp://127.0.0.1:*"))
    before_switch, before_frozen = sys.getswitchinterval(), gc.get_freeze_count()
    seen = {}

    def tick_probe(orig=bridge.serve_requests):
        seen.setdefault("switch", sys.getswitchinterval())  # while serving: lowered for the control loop
        return orig()

    bridge.serve_requests = tick_probe
    bridge.serve(duration_s=0.05)
    assert seen["switch"] < before_switch
    assert sys.getswitchinterval() == before_switch
    assert gc.get_freeze_count() == before_frozen
