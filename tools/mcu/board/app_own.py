# Your own message types, frozen (build.sh with MSGS=<the folder `xrce-client gen-msgs -o` wrote>):
# the heap each type keeps on the board once imported, and with its plan after a first encode and
# decode, on top of what a firmware has loaded before its own types (the message runtime, a first
# type, the string, sequence and array helpers), as bench/micropython/own_types_heap.py measures
# them on the WebAssembly port. At the REPL:
#   import app_own; app_own.main("my_robot_msgs", "WheelTicks SetLed")
import gc


def live():
    gc.collect()
    return gc.mem_alloc()


def main(package, names):
    from xrce.wire.cdr import CdrReader, CdrWriter
    from xrce.msgs.std_msgs import String
    from xrce.msgs.geometry_msgs import Vector3
    from xrce.msgs.sensor_msgs import BatteryState, Image, Imu
    buf = bytearray(2048)

    def round_trip(cls):
        w = CdrWriter(buf)
        cls().encode(w)
        cls.decode(CdrReader(w.getvalue()))

    for cls in (String, Vector3, BatteryState, Image, Imu):
        round_trip(cls)
    cls = None
    print("HEAP before alloc=%d free=%d" % (live(), gc.mem_free()))
    total = live()
    for name in names.split():
        before = live()
        # Through the package, as a board's `from xrce.msgs.<package> import <Type>` does.
        cls = getattr(__import__("xrce.msgs." + package, None, None, (name,)), name)
        imported = live() - before
        round_trip(getattr(cls, "Request", cls))  # a service: its request stands for it
        cls = None
        print("TYPE %s/%s import=%d with_plan=%d" % (package, name, imported, live() - before))
    print("HEAP own types alloc=%d (+%d)" % (live(), live() - total))
    print("DONE")
