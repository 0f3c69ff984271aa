"""Print the objects the RSUs of a corridor see: zenoh, msgpack and jsonschema only (docs/protocol.md).

    python examples/read_object_list.py [CORRIDOR_ID] [N_MESSAGES]      # e.g. while `iea demo` runs
"""
import json
import sys
from pathlib import Path

import jsonschema
import msgpack
import zenoh

corridor, n_messages = sys.argv[1] if len(sys.argv) > 1 else "*", int(sys.argv[2]) if len(sys.argv) > 2 else 10
schema = json.loads((Path(__file__).parent.parent / "protocol/schema/ObjectList.json").read_text())
validator = jsonschema.Draft202012Validator(schema)
fields = schema["$defs"]["DetectedObject"]["x-fields"]  # an object travels as an array in this order

conf = zenoh.Config()
conf.insert_json5("scouting/multicast/interface", '"lo"')  # the services are Zenoh peers on loopback
with zenoh.open(conf) as session:
    subscriber = session.declare_subscriber(f"iea/{corridor}/rsu/*/objects")
    for _, sample in zip(range(n_messages), subscriber, strict=False):
        message = msgpack.unpackb(sample.payload.to_bytes())
        validator.validate(message)  # raises jsonschema.ValidationError for anything but a valid ObjectList
        for row in message["objects"]:
            obj = dict(zip(fields, row, strict=True))
            print(f"{message['rsu_id']} frame {message['frame']}: object {obj['object_id']} {obj['obj_type']} "
                  f"at ({obj['pos_x_m']:.1f}, {obj['pos_y_m']:.1f}) m, {obj['speed_mps']:.1f} m/s")
