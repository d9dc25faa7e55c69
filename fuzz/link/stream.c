// stream.c: libFuzzer target for the host link (firmware/link/link.c), built twice: build/fuzz/link_stream
// (sd_real = double) and build/fuzz/link32_stream (-DSD_SINGLE, the firmware's float). The input's first
// byte chooses what to do:
//
//   even  the rest is a byte stream from the line, fed to the decoder a byte at a time (and, in chunks,
//         to another: the same verdicts at the same bytes, the same frames). Every frame
//         it takes has its length within bounds and, framed again with link_frame, decodes to the
//         same fields and payload; its payload, given to every message's unpack, either is refused
//         or packs back to the same bytes; a payload taken as a request goes through the controller's
//         retransmit rule (an execute moves E on by one; a repeat or refusal leaves it), and into a
//         knot buffer (7 dofs, 16 slots): taken whole or not at all, credits = its free slots.
//   odd   the rest is a robot load: records [type][len][payload] applied in turn to one link_robot
//         (LOAD_ROBOT, LOAD_BODY, LOAD_JOINT, COMMIT), whose commit runs the core's checks on
//         whatever came: every result is a known stage, and an accepted robot's model was set up.
#include "../check.h"
#include "link.h"

static link_decoder g_decoder;
static link_server g_server;
static link_robot g_robot;
static link_knot g_knots[LINK_MAX_PAYLOAD / 16];
static link_ring g_ring;

// unpack as `type`; when accepted, pack again: the same bytes
static void check_payload(uint8_t type, const uint8_t* p, size_t n) {
  uint8_t again[LINK_MAX_PAYLOAD];
  size_t m = 0;
  int rc = LINK_OK;
  switch (type) {
#define SAME(T, name, st)                                  \
  case T: {                                                \
    st v;                                                  \
    rc = link_unpack_##name(p, n, &v);                     \
    if (rc == LINK_OK) m = link_pack_##name(again, sizeof again, &v); \
    break;                                                 \
  }
    SAME(LINK_HELLO, hello, link_hello)
    SAME(LINK_HELLO_REPLY, hello_reply, link_hello_reply)
    SAME(LINK_LOAD_ROBOT, robot_head, link_robot_head)
    SAME(LINK_LOAD_BODY, body, link_body)
    SAME(LINK_LOAD_JOINT, joint, link_joint)
    SAME(LINK_COMMAND, command, link_command)
    SAME(LINK_RESULT, result, link_result)
    SAME(LINK_TELEMETRY, telemetry, link_telemetry)
#undef SAME
    case LINK_KNOTS: {
      link_knots k;
      rc = link_unpack_knots(p, n, &k);
      if (rc == LINK_OK) {
        CHECK(k.count <= sizeof g_knots / sizeof g_knots[0]);
        for (int i = 0; i < k.count; i++) link_knot_at(p, &k, i, &g_knots[i]);
        m = link_pack_knots(again, sizeof again, &k, g_knots);
      }
      break;
    }
    default:
      return;
  }
  CHECK(rc == LINK_OK || rc == LINK_E_PAYLOAD);
  if (rc == LINK_OK) CHECK(m == n && (n == 0 || memcmp(again, p, n) == 0));
}

// The same bytes fed in chunks (link_decoder_feed_bytes, the controller's way; the chunk sizes
// taken from the bytes): the same verdicts at the same bytes, the same frames.
static void chunked(const uint8_t* data, size_t n) {
  static link_decoder one, bulk;
  link_decoder_reset(&one);
  link_decoder_reset(&bulk);
  size_t j = 0;                    // bytes the chunked decoder has taken
  for (size_t k = 0; k < n; k++) {
    int v = link_decoder_feed(&one, data[k]);
    if (v == LINK_MORE) continue;
    int w = LINK_MORE;
    while (w == LINK_MORE && j < n) {
      size_t chunk = 1u + data[j] % 97u, used = 0;
      if (chunk > n - j) chunk = n - j;
      w = link_decoder_feed_bytes(&bulk, data + j, chunk, &used);
      CHECK(used <= chunk && (w != LINK_MORE || used == chunk));
      j += used;
    }
    CHECK(w == v && j == k + 1);
    if (v == LINK_FRAME || v == LINK_BAD_VERSION)
      CHECK(bulk.version == one.version && bulk.seq == one.seq && bulk.ack == one.ack && bulk.type == one.type &&
            bulk.len == one.len && (v != LINK_FRAME || memcmp(bulk.payload, one.payload, one.len) == 0));
  }
  size_t used = 0;
  if (j < n) CHECK(link_decoder_feed_bytes(&bulk, data + j, n - j, &used) == LINK_MORE && used == n - j);
}

static void stream(input* in) {
  chunked(in->p, in->n);
  link_decoder_reset(&g_decoder);
  link_server_reset(&g_server);
  link_ring_reset(&g_ring, 7, 16);
  while (in->n) {
    int v = link_decoder_feed(&g_decoder, take(in));
    CHECK(v >= LINK_BAD_VERSION && v <= LINK_FRAME);
    if (v != LINK_FRAME) continue;
    const link_decoder* d = &g_decoder;
    CHECK(d->len <= LINK_MAX_PAYLOAD && d->version == LINK_VERSION);
    uint8_t payload[LINK_MAX_PAYLOAD], wire[LINK_MAX_WIRE];
    uint8_t seq = d->seq, ack = d->ack, type = d->type;
    uint16_t len = d->len;
    memcpy(payload, d->payload, len);

    size_t w = link_frame(wire, sizeof wire, seq, ack, type, payload, len);
    CHECK(w == len + LINK_HEADER + LINK_CRC + 2u);
    static link_decoder again;
    link_decoder_reset(&again);
    int got = LINK_MORE;
    for (size_t i = 0; i < w; i++) {
      int r = link_decoder_feed(&again, wire[i]);
      CHECK(r == LINK_MORE || i == w - 1);
      got = r;
    }
    CHECK(got == LINK_FRAME && again.seq == seq && again.ack == ack && again.type == type &&
          again.len == len && memcmp(again.payload, payload, len) == 0);

    for (int t = 0; t < 256; t++) check_payload((uint8_t)t, payload, len);

    link_result pushed;
    uint16_t held = g_ring.count;
    link_ring_push(&g_ring, payload, len, &pushed);
    CHECK(pushed.credits == link_ring_free(&g_ring) && g_ring.count <= g_ring.slots);
    CHECK(g_ring.count == held || (pushed.code == LINK_OK && g_ring.count > held));
    if (seq & 1) link_ring_pop(&g_ring);

    link_result reply;
    uint8_t before = g_server.expected;
    int action = link_server_accept(&g_server, seq, type, &reply);
    CHECK(action == LINK_EXECUTE || action == LINK_REPEAT || action == LINK_REFUSE);
    if (action == LINK_EXECUTE) {
      link_result done = {seq, type, LINK_STAGE_LINK, LINK_OK, -1, 0};
      link_server_done(&g_server, &done);
      CHECK(g_server.expected == (uint8_t)(seq + 1));
    } else {
      CHECK(g_server.expected == before && reply.seq == seq);
    }
  }
}

static void robot(input* in) {
  uint8_t payload[LINK_MAX_PAYLOAD];
  while (in->n) {
    uint8_t type = (uint8_t)(LINK_LOAD_ROBOT + take(in) % 4);
    size_t n = take(in) % (LINK_MAX_PAYLOAD + 1);
    for (size_t i = 0; i < n; i++) payload[i] = take(in);
    link_result r = {0, type, 0, 0, -1, 0};
    if (type == LINK_LOAD_ROBOT) {
      link_robot_head h;
      if (link_unpack_robot_head(payload, n, &h) == LINK_OK) link_robot_begin(&g_robot, &h, &r);
    } else if (type == LINK_LOAD_BODY) {
      link_body b;
      if (link_unpack_body(payload, n, &b) == LINK_OK) link_robot_body(&g_robot, &b, &r);
    } else if (type == LINK_LOAD_JOINT) {
      link_joint j;
      if (link_unpack_joint(payload, n, &j) == LINK_OK) link_robot_joint(&g_robot, &j, &r);
    } else {
      link_robot_commit(&g_robot, (uint8_t)(n & 7), &r);
      CHECK(r.stage <= LINK_STAGE_SERVO);
      CHECK((r.stage == LINK_STAGE_LINK && r.code == LINK_OK) == (g_robot.ready == 1));
      if (g_robot.ready) CHECK(g_robot.model.nbody == g_robot.head.nbody && g_robot.model.nq >= g_robot.model.ndof);
    }
  }
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  input in = {data, size};
  uint8_t op = take(&in);
  if (op & 1) {
    memset(&g_robot, 0, sizeof g_robot);
    robot(&in);
  } else {
    stream(&in);
  }
  return 0;
}
