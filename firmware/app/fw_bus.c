// fw_bus.c: the Dynamixel bus of both applications (fw_app.h): set-up, the fast sync read of every
// servo's state, the sync write of the commands, torque off. One packet at a time on the board's
// UART; a reply is waited for with the clock held (board.h), so a tick costs the work it does.
#include "board.h"
#include "fw_app.h"
#include "fw_dynamixel.h"

void fw_bus_init(fw_bus* b, const fw_servo* servo, int n) {
  b->servo = servo;
  b->n = n;
  b->fault_servo = -1;
  for (int i = 0; i < n; i++) b->ids[i] = servo[i].id;
  b->read_len = dxl_fast_sync_read(b->read_packet, sizeof b->read_packet, FW_ADDR_PRESENT, FW_PRESENT_LENGTH,
                                   b->ids, (size_t)n);
}

static void bus_send(fw_bus* b, const uint8_t* packet, size_t n) {
  board_uart_flush();               // a late reply to an earlier packet is stale now
  dxl_reader_reset(&b->reader);
  board_uart_write(packet, n);
}

// Wait, the clock held, until `want` bytes have arrived or the servos are taken for silent;
// then parse what came with the clock running (its cost is the tick's, the waiting is not).
// Returns DXL_PACKET, a negative dxl_feed_ code, or 0 on a timeout. b->rx_got counts the bytes.
static int bus_receive(fw_bus* b, size_t want) {
  b->rx_got = 0;
  for (;;) {
    board_clock_hold();
    int came = board_uart_wait(want - b->rx_got);
    board_clock_release();
    uint8_t chunk[128];
    size_t n;
    while ((n = board_uart_take(chunk, sizeof chunk)) > 0) {
      size_t used;
      int status = dxl_reader_feed_bytes(&b->reader, chunk, n, &used);
      b->rx_got += used;
      if (status != DXL_MORE) return status;
    }
    if (!came) return 0;
    want = b->rx_got + 1;          // stuffing made the packet longer: wait for one more byte
  }
}

// One status packet from servo `id` (after a ping, read or write); 0 or a fault code.
static int bus_status(fw_bus* b, uint8_t id) {
  int status = bus_receive(b, 11);    // the shortest status packet: no parameters
  if (status == 0) return FW_FAULT_TIMEOUT;
  if (status != DXL_PACKET || b->reader.id != id || b->reader.instruction != DXL_STATUS)
    return FW_FAULT_CORRUPT;
  if (b->reader.error) return FW_FAULT_STATUS;
  return FW_OK;
}

static int bus_write_bytes(fw_bus* b, uint8_t id, uint16_t address, const uint8_t* data, uint16_t size) {
  size_t n = dxl_write(b->tx, sizeof b->tx, id, address, data, size);
  bus_send(b, b->tx, n);
  return bus_status(b, id);
}

static int bus_write(fw_bus* b, uint8_t id, uint16_t address, uint8_t value) {
  return bus_write_bytes(b, id, address, &value, 1);
}

void fw_bus_torque_off(fw_bus* b) {
  uint8_t zeros[SD_MAX_DOF] = {0};
  size_t n = dxl_sync_write(b->tx, sizeof b->tx, FW_ADDR_TORQUE_ENABLE, 1, b->ids, (size_t)b->n, zeros);
  board_uart_write(b->tx, n);        // a sync write is never answered: nothing to wait for
}

// the length of a fast sync read reply (never stuffed): header, id, length, instruction, then per
// servo error, id, data and a CRC (the last servo's is the packet's)
static size_t fast_reply_length(const fw_bus* b) {
  return 4 + 1 + 2 + 1 + (size_t)b->n * (1u + 1u + FW_PRESENT_LENGTH + 2u);
}

int fw_bus_read(fw_bus* b, sd_real* q, sd_real* qd, sd_real* current) {
  bus_send(b, b->read_packet, b->read_len);
  int status = bus_receive(b, fast_reply_length(b));
  if (status == 0) {        // the reply stopped short: name the first servo whose block is missing
    long body = (long)b->rx_got - 8;
    int k = body < 0 ? 0 : (int)(body / (long)(1 + 1 + FW_PRESENT_LENGTH + 2));
    b->fault_servo = b->ids[k < b->n ? k : b->n - 1];
    return FW_FAULT_TIMEOUT;
  }
  dxl_block blocks[SD_MAX_DOF];
  int good = status == DXL_PACKET
                 ? dxl_fast_reply_split(&b->reader, FW_PRESENT_LENGTH, b->ids, (size_t)b->n, blocks)
                 : -1;
  if (good != b->n) {  // a bad CRC names no servo; a bad block names its own
    b->fault_servo = good < 0 ? -1 : b->ids[good];
    return FW_FAULT_CORRUPT;
  }
  for (int i = 0; i < b->n; i++) {
    const fw_servo* s = &b->servo[i];
    if (blocks[i].error) {
      b->fault_servo = s->id;
      return FW_FAULT_STATUS;
    }
    const uint8_t* p = blocks[i].data;
    b->current_units[i] = dxl_get_i16(p);
    sd_real current_units = (sd_real)b->current_units[i];
    sd_real velocity_units = (sd_real)dxl_get_i32(p + 2);
    sd_real position_ticks = (sd_real)dxl_get_i32(p + 6);
    sd_real to_joint = s->direction / s->gear_ratio;     // direction is +-1: its own inverse
    q[i] = (position_ticks * s->rad_per_tick - s->zero_offset) * to_joint;
    qd[i] = velocity_units * s->radps_per_unit * to_joint;
    current[i] = s->direction * current_units * s->amp_per_unit;
  }
  return FW_OK;
}

void fw_bus_write_goals(fw_bus* b, const int16_t* goal) {
  uint8_t data[2 * SD_MAX_DOF];
  for (int i = 0; i < b->n; i++) dxl_put_u16(data + 2 * i, (uint16_t)goal[i]);
  size_t n = dxl_sync_write(b->tx, sizeof b->tx, FW_ADDR_GOAL_CURRENT, 2, b->ids, (size_t)b->n, data);
  board_uart_write(b->tx, n);
}

static int setup_servo(fw_bus* b, int i) {
  const fw_servo* s = &b->servo[i];
  size_t n = dxl_ping(b->tx, sizeof b->tx, s->id);
  bus_send(b, b->tx, n);
  int err = bus_status(b, s->id);
  if (err == FW_OK && (b->reader.nparam < 3 || dxl_get_u16(b->reader.param) != s->model_number))
    err = FW_FAULT_SETUP;
  if (err == FW_OK) err = bus_write(b, s->id, FW_ADDR_TORQUE_ENABLE, 0);    // EEPROM needs torque off
  if (err == FW_OK) err = bus_write(b, s->id, FW_ADDR_RETURN_DELAY, 0);
  if (err == FW_OK) err = bus_write(b, s->id, FW_ADDR_OPERATING_MODE, FW_MODE_CURRENT);
  if (err == FW_OK) err = bus_write(b, s->id, FW_ADDR_BUS_WATCHDOG, 0);     // clear a tripped one
  return err;
}

int fw_bus_setup(fw_bus* b) {
  for (int i = 0; i < b->n; i++) {
    int err = setup_servo(b, i);
    if (err) {
      b->fault_servo = b->servo[i].id;
      return err;
    }
  }
  // Goal Current 0 before torque on: a servo powers up with Goal Current at its Current Limit,
  // which torque on would apply at once, for as long as the set-up of the other servos lasts
  const uint8_t zero_current[2] = {0, 0};
  for (int i = 0; i < b->n; i++) {
    uint8_t id = b->servo[i].id;
    int err = bus_write_bytes(b, id, FW_ADDR_GOAL_CURRENT, zero_current, 2);
    if (err == FW_OK) err = bus_write(b, id, FW_ADDR_TORQUE_ENABLE, 1);
    if (err == FW_OK) err = bus_write(b, id, FW_ADDR_BUS_WATCHDOG, FW_BUS_WATCHDOG_UNITS);
    if (err) {
      b->fault_servo = id;
      return err;
    }
  }
  return FW_OK;
}
