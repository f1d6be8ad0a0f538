# Your own message types, frozen (build.sh with MSGS=<the folder `xrce-client gen-msgs -o` wrote>):
# the heap each type keeps on the board once imported, and with its plan after a first encode and
# decode, on top of what a firmware has loaded before its own types (the message runtime, a first
# type, the string, sequence and array helpers), as bench/micropython/own_types_heap.py measures
# them on the WebAssembly port; then what declaring a type hash (xrce.client.type_hash) keeps. At the REPL:
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
    # Declaring a type hash at creation (xrce.client.type_hash, only for a board that uses it): the
    # module kept loaded and one endpoint blob with the hash, as its create_writer writes it (the
    # session keeps that blob in its re-creation log).
    import xrce.client  # a board declaring hashes has its session loaded: not counted here
    before = live()
    try:
        from xrce.client.type_hash import endpoint_blob, user_data
        cls = getattr(__import__("xrce.msgs." + package, None, None, (names.split()[0],)), names.split()[0])
        data = user_data(cls)
        print("TYPE_HASH %s %s" % (cls.ROS_TYPE, data.decode()))
        blob = endpoint_blob(0x0015, 0x0003, 10, data, False)
        data = cls = None
        print("HEAP type_hash used +%d (blob %d bytes)" % (live() - before, len(blob)))
    except ValueError as error:  # classes generated without rosidl: no hashes to declare
        print("TYPE_HASH none: %s" % error)
    print("DONE")
