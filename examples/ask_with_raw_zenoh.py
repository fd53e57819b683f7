"""Ask a ktbt peer for knowledge using eclipse-zenoh directly, from spec/protocol.md alone.

    python examples/ask_with_raw_zenoh.py tcp/127.0.0.1:7447 "<c>(TargetSeen,colour=2)"

Prints the first response (JSON) and exits 0, or exits 1 if no peer answered in time.
"""

import json
import sys
import uuid

import zenoh


def main() -> int:
    endpoint, sequence = sys.argv[1], sys.argv[2]
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    query = {"v": 1, "type": "query", "id": uuid.uuid4().hex, "sender": "raw", "sequence": sequence}
    with zenoh.open(config) as session:
        # Wait until a ktbt peer is present (its liveliness token), then ask everyone.
        for _ in range(50):
            if any(r.ok for r in session.liveliness().get("ktbt/v1/peers/*", timeout=0.2)):
                break
        for reply in session.get("ktbt/v1/knowledge/*", payload=json.dumps(query), timeout=3.0):
            if reply.ok is None:
                continue
            answer = json.loads(reply.ok.payload.to_bytes())
            if answer.get("type") == "response" and answer.get("id") == query["id"]:
                print(json.dumps(answer))
                return 0
    return 1


if __name__ == "__main__":
    sys.exit(main())
