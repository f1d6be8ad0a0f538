# Samples from ROS that the board's classes cannot read: type drift, said once per reader.
#
# The agent checks what a board writes against its own package (xrce/agent/engine/type_drift.py);
# what ROS sends a board only the board can check, against the classes it was given. A sample
# that its class reads past the end of, or leaves more than a payload's alignment padding (3
# bytes) of unread, was written from another definition of the type: the classes were generated
# from another version of the .msg than the ROS side's package. The session's decoding tells
# (xrce.client.session._on_data) and this module, loaded only then, counts it in
# ``session.type_drift`` and prints one line per reader. A drift of fewer than 4 bytes at the
# end (a uint8 field added last) cannot be told from padding.


from xrce import DecodeError


def drifted(session, reader_id, msg_class, unread):
    # ``unread``: bytes left after the class's last field, or -1 when it read past the end (then
    # the sample is not handed to the reader: DecodeError, which the session counts as before).
    session.type_drift = getattr(session, "type_drift", 0) + 1
    named = getattr(session, "_drift_named", None)
    if named is None:
        named = session._drift_named = set()
    if reader_id not in named:
        named.add(reader_id)
        _say(reader_id, msg_class, unread)
    if unread < 0:
        raise DecodeError("sample past its end")


def _say(reader_id, msg_class, unread):
    cls = msg_class if type(msg_class) is type else type(msg_class)
    what = "reads past its end" if unread < 0 else "leaves %d bytes unread" % unread
    print("xrce: reader 0x%04X: a sample from ROS is not %s as this board's classes define it (it %s);"
          " regenerate the board's classes (xrce-client gen-msgs) or rebuild the agent's package"
          " from the same .msg" % (reader_id, getattr(cls, "ROS_TYPE", cls.__name__), what))
