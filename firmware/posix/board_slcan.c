// board_slcan.c: the Linux board's CAN bus (fw_can.h's board_can_*) through an SLCAN adapter on a
// tty (can=PATH): the Lawicel ASCII protocol that CANable and similar adapters, python-can's slcan
// interface and the simulator's adapter (sim/transport/can.py) speak. Open: `C` (closed, in case),
// `S0`..`S8` (the bit rate), `O` (open), each answered CR (BEL: refused). A frame out is
// `tIIILDD..` CR (id 3 hex digits, length 1, data 2 a byte), acknowledged `z` CR (or CR); the
// frames heard come as the same `t` lines. Extended, remote and FD lines, time stamps and status
// answers are taken and dropped: the motors speak classic 11-bit frames.
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "board_posix.h"
#include "fw_can.h"

#define LINE_MAX_CHARS 160u           // a 64-byte FD frame is 138 characters
#define QUEUE 64u                     // frames heard and not yet taken

typedef struct { uint16_t id; uint8_t len, data[8]; } frame;

static int g_can = -1;
static char g_line[LINE_MAX_CHARS];
static unsigned g_line_n;
static frame g_queue[QUEUE];
static unsigned g_head, g_count;
static unsigned g_refused;            // BEL answers: lines the adapter refused
static unsigned g_lost;               // frames dropped: the queue was full

static uint64_t mono_ms(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (uint64_t)t.tv_sec * 1000u + (uint64_t)t.tv_nsec / 1000000u;
}

int board_posix_can_open(const char* path) {
  g_can = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
  if (g_can < 0) {
    fprintf(stderr, "servodyn-fw: the CAN adapter %s: cannot open (%s)\n", path, strerror(errno));
    return -1;
  }
  struct termios tio;
  if (tcgetattr(g_can, &tio) == 0) {   // a USB adapter's ACM tty, or the simulator's pseudo-terminal
    cfmakeraw(&tio);
    tio.c_cflag |= CLOCAL | CREAD;
    tio.c_cc[VMIN] = 0;
    tio.c_cc[VTIME] = 0;
    tcsetattr(g_can, TCSANOW, &tio);
  }
  return 0;
}

static int hex(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

// one line without its CR: a `t` frame goes into the queue, anything else is dropped
static void line(const char* s, unsigned n) {
  if (n < 5 || s[0] != 't') return;
  int id = 0;
  for (int k = 1; k <= 3; k++) {
    int h = hex(s[k]);
    if (h < 0) return;
    id = id << 4 | h;
  }
  int len = hex(s[4]);
  if (len < 0 || len > 8 || n < 5u + 2u * (unsigned)len) return;
  frame f = {.id = (uint16_t)id, .len = (uint8_t)len};
  for (int k = 0; k < len; k++) {
    int hi = hex(s[5 + 2 * k]), lo = hex(s[6 + 2 * k]);
    if (hi < 0 || lo < 0) return;
    f.data[k] = (uint8_t)(hi << 4 | lo);
  }
  if (g_count == QUEUE) {
    g_lost++;
    return;
  }
  g_queue[(g_head + g_count++) % QUEUE] = f;
}

// what the adapter sent so far, without waiting; the number of answers (CR or BEL) in it
static int pump(void) {
  char chunk[512];
  int answers = 0;
  ssize_t r;
  while ((r = read(g_can, chunk, sizeof chunk)) > 0) {
    for (ssize_t k = 0; k < r; k++) {
      char c = chunk[k];
      if (c == '\r' || c == '\a') {
        if (c == '\a') g_refused++;
        else line(g_line, g_line_n);
        g_line_n = 0;
        answers++;
      } else if (c != '\n' && g_line_n < LINE_MAX_CHARS) {
        g_line[g_line_n++] = c;
      }
    }
  }
  return answers;
}

static int write_all(const char* text, size_t n) {
  uint64_t deadline = mono_ms() + (uint64_t)board_posix_reply_ms();
  while (n > 0) {
    ssize_t w = write(g_can, text, n);
    if (w > 0) {
      text += w;
      n -= (size_t)w;
    } else if (w < 0 && errno != EINTR && errno != EAGAIN) {
      return 0;
    } else {
      if (mono_ms() >= deadline) return 0;
      struct pollfd p = {g_can, POLLOUT, 0};
      poll(&p, 1, 10);
    }
  }
  return 1;
}

int board_can_open(uint32_t bitrate) {
  static const uint32_t rates[9] = {10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000};
  if (g_can < 0) return 0;
  int code = -1;
  for (int k = 0; k < 9; k++)
    if (rates[k] == bitrate) code = k;
  if (code < 0) {
    fprintf(stderr, "servodyn-fw: an SLCAN adapter has no %u bit/s (10 k .. 1 M, S0 .. S8)\n", (unsigned)bitrate);
    return 0;
  }
  char text[16];
  int n = snprintf(text, sizeof text, "C\rS%d\rO\r", code);
  pump();
  unsigned refused = g_refused;
  if (!write_all(text, (size_t)n)) return 0;
  int answers = 0;
  uint64_t deadline = mono_ms() + 1000u;            // an adapter answers at once
  while (answers < 3 && mono_ms() < deadline) {
    struct pollfd p = {g_can, POLLIN, 0};
    poll(&p, 1, 10);
    answers += pump();
  }
  // `C` on a closed adapter may be refused; `S` and `O` may not
  if (answers < 3 || g_refused - refused > 1) {
    fprintf(stderr, "servodyn-fw: the SLCAN adapter did not open at %u bit/s (%d answers, %u refused)\n",
            (unsigned)bitrate, answers, g_refused - refused);
    return 0;
  }
  g_count = 0;
  return 1;
}

int board_can_send(uint16_t id, const uint8_t* data, uint8_t len) {
  static const char digits[] = "0123456789ABCDEF";
  if (g_can < 0 || len > 8) return 0;
  char text[5 + 16 + 1];
  unsigned n = 0;
  text[n++] = 't';
  text[n++] = digits[id >> 8 & 0x7u];
  text[n++] = digits[id >> 4 & 0xFu];
  text[n++] = digits[id & 0xFu];
  text[n++] = digits[len];
  for (unsigned k = 0; k < len; k++) text[n++] = digits[data[k] >> 4], text[n++] = digits[data[k] & 0xFu];
  text[n++] = '\r';
  board_posix_bus_used();
  return write_all(text, n);
}

int board_can_take(uint16_t* id, uint8_t* data, uint8_t* len) {
  if (g_can < 0) return 0;
  if (!g_count) pump();
  if (!g_count) return 0;
  const frame* f = &g_queue[g_head];
  g_head = (g_head + 1) % QUEUE;
  g_count--;
  *id = f->id;
  *len = f->len;
  memcpy(data, f->data, f->len);
  return 1;
}

int board_can_wait(void) {
  if (g_can < 0) return 0;
  uint64_t deadline = mono_ms() + (uint64_t)board_posix_reply_ms();
  for (;;) {
    pump();
    if (g_count) return 1;
    uint64_t now = mono_ms();
    if (now >= deadline) return 0;
    struct pollfd p = {g_can, POLLIN, 0};
    if (poll(&p, 1, (int)(deadline - now)) < 0 && errno != EINTR) return 0;
  }
}
