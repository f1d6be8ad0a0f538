"""rclpy's parameter and logger services, loaded only if a node of the agent process starts them.

``rclpy.node`` imports ``rclpy.parameter_service`` and ``rclpy.logging_service`` at start-up, and
with them every service type of ``rcl_interfaces`` (eight, each a request, a response and an event
class): 0.5 MB of the agent's resident memory. The agent's nodes start neither service
(``start_parameter_services=False``, no logger service), so the two modules are deferred
(``xrce.agent.middleware.ros.deferred``): their classes are stand-ins that run the real module when a node
constructs one, and ``rcl_interfaces.srv`` holds the one type ``rclpy.node`` names
(``ListParameters``) until any other name is asked of it, which runs the package whole. A client
that creates a service of an ``rcl_interfaces`` type gets the real package that way.

Only ``xrce-agent`` itself calls ``defer_unused()`` (``xrce.agent.cli``, ROS middleware), before
``rclpy.node`` is imported; a program that uses ``xrce.agent`` as a library imports rclpy as usual.
"""

from __future__ import annotations

import sys

from xrce.agent.middleware.ros import deferred

_SERVICE_MODULES = (("rclpy.parameter_service", "ParameterService"),
                    ("rclpy.logging_service", "LoggingService"))


def _list_parameters_only(package) -> None:
    from rcl_interfaces.srv._list_parameters import ListParameters
    package.ListParameters = ListParameters


def defer_unused() -> None:
    """Defer what is described above; nothing for a module imported already (then it stays as
    it is: e.g. ``rclpy.node`` was imported first)."""
    if "rclpy.node" in sys.modules:
        return
    for module_name, class_name in _SERVICE_MODULES:
        deferred.defer(module_name, lambda module, name=class_name: setattr(
            module, name, deferred.on_first_call(module, name)))
    deferred.defer("rcl_interfaces.srv", _list_parameters_only)
