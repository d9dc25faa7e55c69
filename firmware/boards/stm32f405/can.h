// can.h: bxCAN1 of the STM32F405 for CAN motors (PB8 CAN1_RX, PB9 CAN1_TX, alternate function 9,
// to a 3.3 V transceiver such as the SN65HVD230): classic CAN frames, polled -- the MIT-protocol
// codec (hal/can/c/canmotor.c) packs and unpacks their data.
//
// No QEMU machine models a CAN controller: this driver runs on the host against a register-level
// test double (tests/f405/can_double.c, tests/test_f405_can.py) and on silicon.
#ifndef F405_CAN_H
#define F405_CAN_H

#include <stdint.h>

typedef struct f405_can_frame_ {
  uint32_t id;        // 11-bit standard or 29-bit extended identifier
  uint8_t extended;   // 1: a 29-bit identifier
  uint8_t len;        // data bytes, 0..8
  uint8_t data[8];
} f405_can_frame;

enum {
  F405_CAN_OK = 0,
  F405_CAN_BITRATE = -1,   // APB1's 42 MHz gives no 14-time-quantum bit at this rate
  F405_CAN_TIMEOUT = -2,   // the controller did not enter or leave initialisation (no bus, no clock)
  F405_CAN_FULL = -3,      // all three transmit mailboxes are pending
  F405_CAN_ARGUMENT = -4,  // a frame longer than 8 bytes, an identifier too wide, a bank > 13
};

// Bit timing at APB1 = 42 MHz, 14 time quanta a bit (sync 1, segment 1 11, segment 2 2: sample at
// 85.7 %, SJW 1): prescaler = 42 MHz / (14 x bitrate), an integer for 1 Mbit/s (3), 500 (6),
// 250 (12) and 125 kbit/s (24). The BTR word, or 0 when the rate is not one of those exact ones.
uint32_t f405_can_timing(uint32_t bitrate);
// Leave sleep, enter initialisation, set the timing (loopback: the controller hears its own
// frames, for a bench test without a bus), automatic bus-off recovery, transmit in request order,
// and leave initialisation: once 11 recessive bits are on the bus. Every wait bounded.
int f405_can_init(uint32_t bitrate, int loopback);
// Filter bank `bank` (0..13: CAN1's share) into FIFO 0, 32-bit mask mode: a frame is accepted when
// (its identifier & mask) == (id & mask), standard or extended as `extended` says. mask 0 accepts
// every frame of that kind.
int f405_can_filter(int bank, uint32_t id, uint32_t mask, int extended);
// Queue a frame in a free transmit mailbox; F405_CAN_FULL when none is free (try again later).
int f405_can_send(const f405_can_frame* frame);
// Take the oldest frame of receive FIFO 0: 1, or 0 when it is empty.
int f405_can_receive(f405_can_frame* frame);
// Frames lost because FIFO 0 was full (its three mailboxes), since f405_can_init.
uint32_t f405_can_overruns(void);

#endif  // F405_CAN_H
