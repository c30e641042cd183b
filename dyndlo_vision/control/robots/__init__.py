"""Robot drivers behind the ``Robot`` protocol: ABB EGM and UR RTDE joint streaming, and fake controllers.

The drivers' optional dependency (``abb-robot-client`` for EGM) is imported when a driver connects, so this
package imports without it: ``pip install 'dyndlo_vision[robot]'`` for hardware.
"""

from dyndlo_vision.control.robots._streaming import JointSample, JointStreamingDriver
from dyndlo_vision.control.robots.egm import EgmRobot
from dyndlo_vision.control.robots.fake_servers import FakeEgmController, FakeRtdeController, ReceivedTarget
from dyndlo_vision.control.robots.rtde import RtdeRobot

__all__ = [
    "EgmRobot",
    "FakeEgmController",
    "FakeRtdeController",
    "JointSample",
    "JointStreamingDriver",
    "ReceivedTarget",
    "RtdeRobot",
]
