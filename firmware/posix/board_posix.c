// board_posix.c: the firmware's board layer for Linux (the native loop), as Zephyr's native_sim
// runs Zephyr firmware as a process. The same application (firmware/app) runs on it unchanged.
//
//   UART     a termios serial port in raw mode: a USB adapter (/dev/ttyUSB0, its latency timer
//            asked down to 1 ms through ASYNC_LOW_LATENCY) or the simulated bus's pseudo-terminal
//   CAN      an SLCAN adapter on a tty (can=PATH; board_slcan.c), the general application's
//   SysTick  clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME) to each period's start (real time),
//            or, in lock-step, a virtual clock that jumps to the next period at once and is held
//            while the simulated bus answers (as the QEMU run's -icount clock): no deadline
//   console  standard output; the exit status is the fault code
//   priority SCHED_FIFO and mlockall in real time when the process may, one line when it may not
//
// Command line: servodyn-fw [PORT] [realtime] [log=FILE] [reply_ms=N] [link=PATH] [can=PATH]
// [period_us=N] [nan_at=K] [ticks=N]; the last three are the application's (fw_main.c). PORT, the
// Dynamixel bus, may be left out when the robot has none (a CAN arm: can=PATH, the SLCAN adapter). log=FILE: one binary
// record per tick (fw_record_tick) for the host tools. link=PATH: the host link's line (fw_link.c,
// build/fw/native/servodyn-fw-link), a pseudo-terminal (set raw) or a socket; in lock-step a tick
// that did not use the bus waits for the host's bytes up to one period of real time, so an idle
// controller does not spin, and a frame waits for room on the line (up to 1 s) rather than being
// dropped, so the host gets every tick's telemetry; in real time a full line drops the frame.
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <linux/serial.h>
#include <poll.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "board.h"
#include "board_posix.h"
#include "fw_app.h"

int fw_app_main(void);           // firmware/app/fw_main.c's main, renamed in this build

static char g_cmdline[256];
static int g_fd = -1;
static int g_realtime;
static long g_reply_ms = 250;    // a pseudo-terminal on a loaded machine can hold bytes ~140 ms
static FILE* g_log;
static int g_link_fd = -1;
static int g_bus_used;           // a bus was written since the last wait (lock-step)

long board_posix_reply_ms(void) { return g_reply_ms; }
void board_posix_bus_used(void) { g_bus_used = 1; }

// the clock, in ns (BOARD_CPU_HZ is 1e9 in this build)
static struct timespec g_start;
static uint64_t g_period_ns, g_virtual, g_skipped, g_held, g_hold_at;
static uint32_t g_ticks;
static uint64_t g_cpu_at_tick, g_tick_began;

#define RX_SIZE 1024u
static uint8_t g_rx[RX_SIZE];
static size_t g_rx_n;

static uint64_t mono_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}

static uint64_t cpu_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}

static uint64_t start_ns(void) {
  return (uint64_t)g_start.tv_sec * 1000000000u + (uint64_t)g_start.tv_nsec;
}

//---------------------------------- console -----------------------------------------------------

void board_write(const char* text) {
  fputs(text, stdout);
  fflush(stdout);
}

void board_write_int(long value) {
  printf("%ld", value);
  fflush(stdout);
}

void board_stop(int code) {
  if (g_log) fclose(g_log);
  exit(code);
}

void board_stack_paint(void) {}

unsigned board_stack_used(void) {
  return 0;                      // the host's stack is not the board's: nothing to measure
}

int board_cmdline(char* text, unsigned size) {
  if (size == 0) return -1;
  strncpy(text, g_cmdline, size - 1);
  text[size - 1] = 0;
  return (int)strlen(text);
}

//---------------------------------- clock -------------------------------------------------------
// now = time since the start, less the time held (lock-step) plus the time skipped to each next
// period (lock-step: the wait costs nothing); in real time nothing is held or skipped.

static uint64_t elapsed(void) {
  return mono_ns() - start_ns() - g_held + g_skipped;
}

void board_clock_start(uint32_t period) {
  g_period_ns = period;
  clock_gettime(CLOCK_MONOTONIC, &g_start);
  g_virtual = g_skipped = g_held = 0;
  g_ticks = 0;
}

uint32_t board_clock_now(void) {
  return (uint32_t)elapsed();
}

uint32_t board_clock_ticks(void) {
  if (g_realtime) return (uint32_t)(elapsed() / g_period_ns);
  return g_ticks;                // lock-step: a period begins only when the loop waits for it
}

void board_clock_wait(void) {
  if (g_realtime) {
    uint64_t next = ((uint64_t)board_clock_ticks() + 1u) * g_period_ns + start_ns();
    struct timespec at = {(time_t)(next / 1000000000u), (long)(next % 1000000000u)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, NULL) == EINTR) {
    }
  } else {
    if (!g_bus_used && g_link_fd >= 0) {     // idle: wait for the host, not for the bus
      struct pollfd p = {g_link_fd, POLLIN, 0};
      poll(&p, 1, (int)((g_period_ns + 999999u) / 1000000u));
    }
    g_bus_used = 0;
    uint64_t now = elapsed();
    uint64_t next = (now / g_period_ns + 1u) * g_period_ns;
    g_skipped += next - now;
    g_ticks++;
  }
}

void board_tick_begin(void) {     // the log times each tick from here, a caught-up one too
  g_tick_began = mono_ns();
  g_cpu_at_tick = cpu_ns();
}

void board_clock_hold(void) {
  if (!g_realtime) g_hold_at = mono_ns();
}

void board_clock_release(void) {
  if (!g_realtime) g_held += mono_ns() - g_hold_at;
}

//---------------------------------- UART --------------------------------------------------------

static speed_t speed_of(uint32_t baud) {
  switch (baud) {
    case 9600: return B9600;
    case 57600: return B57600;
    case 115200: return B115200;
    case 1000000: return B1000000;
    case 2000000: return B2000000;
    case 3000000: return B3000000;
    case 4000000: return B4000000;
    default: return 0;
  }
}

void board_uart_init(uint32_t baud) {
  if (g_fd < 0) return;          // no Dynamixel bus: a robot with a servo on one faults at its set-up
  struct termios tio;
  if (tcgetattr(g_fd, &tio) != 0) {
    fprintf(stderr, "servodyn-fw: the port is not a serial port (%s)\n", strerror(errno));
    board_stop(FW_FAULT_SETUP);
  }
  cfmakeraw(&tio);
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  speed_t speed = speed_of(baud);
  if (speed == 0) {
    fprintf(stderr, "servodyn-fw: %u baud has no termios speed here (9600 .. 4000000)\n", (unsigned)baud);
    board_stop(FW_FAULT_SETUP);
  }
  cfsetispeed(&tio, speed);
  cfsetospeed(&tio, speed);
  if (tcsetattr(g_fd, TCSANOW, &tio) != 0) {
    fprintf(stderr, "servodyn-fw: cannot set the port raw (%s)\n", strerror(errno));
    board_stop(FW_FAULT_SETUP);
  }
  struct serial_struct serial;    // a USB adapter: 1 ms latency timer (a pseudo-terminal has none)
  if (ioctl(g_fd, TIOCGSERIAL, &serial) == 0) {
    serial.flags |= ASYNC_LOW_LATENCY;
    ioctl(g_fd, TIOCSSERIAL, &serial);
  }
  tcflush(g_fd, TCIOFLUSH);
  g_rx_n = 0;
}

void board_uart_write(const uint8_t* data, size_t n) {
  g_bus_used = 1;
  if (g_fd < 0) return;
  while (n > 0) {
    ssize_t w = write(g_fd, data, n);
    if (w < 0) {
      if (errno == EINTR || errno == EAGAIN) continue;
      fprintf(stderr, "servodyn-fw: the port stopped taking bytes (%s)\n", strerror(errno));
      board_stop(FW_FAULT_TIMEOUT);
    }
    data += w;
    n -= (size_t)w;
  }
}

static void pump(void) {          // what the port holds now, without waiting
  if (g_rx_n >= RX_SIZE || g_fd < 0) return;
  ssize_t r = read(g_fd, g_rx + g_rx_n, RX_SIZE - g_rx_n);
  if (r > 0) g_rx_n += (size_t)r;
}

int board_uart_read(uint8_t* byte) {
  return board_uart_take(byte, 1) == 1;
}

size_t board_uart_take(uint8_t* out, size_t cap) {
  pump();
  size_t n = g_rx_n < cap ? g_rx_n : cap;
  memcpy(out, g_rx, n);
  memmove(g_rx, g_rx + n, g_rx_n - n);
  g_rx_n -= n;
  return n;
}

size_t board_uart_available(void) {
  pump();
  return g_rx_n;
}

int board_uart_wait(size_t want) {
  uint64_t deadline = mono_ns() + (uint64_t)g_reply_ms * 1000000u;
  for (;;) {
    pump();
    if (g_rx_n >= want) return 1;
    uint64_t now = mono_ns();
    if (now >= deadline || g_fd < 0) return 0;
    struct pollfd p = {g_fd, POLLIN, 0};
    int ms = (int)((deadline - now + 999999u) / 1000000u);
    if (poll(&p, 1, ms) < 0 && errno != EINTR) return 0;
  }
}

void board_uart_flush(void) {
  pump();
  g_rx_n = 0;
}

uint32_t board_uart_overruns(void) {
  return 0;                      // the kernel buffers what the loop has not taken
}

//---------------------------------- the host link's line ---------------------------------------

void board_link_init(void) {
  struct termios tio;
  if (g_link_fd < 0 || tcgetattr(g_link_fd, &tio) != 0) return;   // a socket: nothing to set
  cfmakeraw(&tio);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  tcsetattr(g_link_fd, TCSANOW, &tio);
}

int board_link_write(const uint8_t* data, size_t n) {
  if (g_link_fd < 0) return 0;
  size_t sent = 0;
  while (sent < n) {
    ssize_t w = write(g_link_fd, data + sent, n - sent);
    if (w > 0) {
      sent += (size_t)w;
    } else if (w < 0 && errno == EINTR) {
      continue;
    } else if (sent == 0 && g_realtime) {
      return 0;                  // full: the frame is dropped whole (real time waits for no host)
    } else {                     // begun: finish it, or the host loses this frame and the next;
      struct pollfd p = {g_link_fd, POLLOUT, 0};    // lock-step waits for the host, as for the bus
      if (poll(&p, 1, g_realtime ? 10 : 1000) <= 0) return 0;
    }
  }
  return 1;
}

size_t board_link_take(uint8_t* out, size_t cap) {
  if (g_link_fd < 0) return 0;
  ssize_t r = read(g_link_fd, out, cap);
  return r > 0 ? (size_t)r : 0;
}

//---------------------------------- the per-tick log --------------------------------------------
// One record a tick, native doubles: tick, start (s on the monotonic clock from the start), wall
// and CPU time of its work (s), then q_d, q, qd, tau, current (njoint each).
// servodyn.tools.native reads it.

void fw_record_tick(long tick, int njoint, const sd_real* q_d, const sd_real* q, const sd_real* qd,
                    const sd_real* tau, const sd_real* current) {
  if (!g_log) return;
  enum { HEAD = 4 };
  double row[HEAD + 5 * SD_MAX_DOF];
  row[0] = (double)tick;
  row[1] = (double)(g_tick_began - start_ns()) * 1e-9;
  row[2] = (double)(mono_ns() - g_tick_began) * 1e-9;
  row[3] = (double)(cpu_ns() - g_cpu_at_tick) * 1e-9;
  const sd_real* parts[5] = {q_d, q, qd, tau, current};
  for (int p = 0; p < 5; p++)
    for (int i = 0; i < njoint; i++) row[HEAD + p * njoint + i] = (double)parts[p][i];
  fwrite(row, sizeof(double), (size_t)(HEAD + 5 * njoint), g_log);
}

//---------------------------------- main --------------------------------------------------------

static void realtime_setup(void) {
  struct sched_param param = {.sched_priority = 80};
  if (sched_setscheduler(0, SCHED_FIFO, &param) != 0)
    fprintf(stderr, "servodyn-fw: SCHED_FIFO not allowed (%s): the loop runs at normal priority\n",
            strerror(errno));
  if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0)
    fprintf(stderr, "servodyn-fw: mlockall not allowed (%s): pages may fault in the loop\n", strerror(errno));
}

// link=pty: the host link on a new pseudo-terminal, as a board's USB serial port appears: its path
// on standard error ("servodyn-fw-link: the host link is on /dev/pts/N"), for `servodyn swing
// --controller /dev/pts/N`. This process holds the terminal's side open too, so a host that closes
// it and opens it again finds the controller as it left it (idle, or its watchdog run out).
static int open_link_pty(void) {
  int fd = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK);
  if (fd < 0 || grantpt(fd) != 0 || unlockpt(fd) != 0) {
    fprintf(stderr, "servodyn-fw: the host link: no pseudo-terminal (%s)\n", strerror(errno));
    return -1;
  }
  const char* path = ptsname(fd);
  int held = path ? open(path, O_RDWR | O_NOCTTY) : -1;
  struct termios tio;
  if (held < 0 || tcgetattr(held, &tio) != 0) {
    fprintf(stderr, "servodyn-fw: the host link: cannot open %s (%s)\n", path ? path : "?", strerror(errno));
    return -1;
  }
  cfmakeraw(&tio);
  tcsetattr(held, TCSANOW, &tio);
  g_link_fd = fd;
  fprintf(stderr, "servodyn-fw-link: the host link is on %s\n", path);
  fflush(stderr);
  return 0;
}

int main(int argc, char** argv) {
  if (argc < 2 || argv[1][0] == '-') {
    fprintf(stderr, "usage: %s [PORT] [realtime] [log=FILE] [reply_ms=N] [link=PATH|pty] [can=PATH] [period_us=N] "
            "[nan_at=K] [ticks=N]\n",
            argv[0]);
    return 2;
  }
  const char* port = strchr(argv[1], '=') || strcmp(argv[1], "realtime") == 0 ? NULL : argv[1];
  size_t used = 0;
  for (int k = port ? 2 : 1; k < argc; k++) {
    if (strcmp(argv[k], "realtime") == 0) {
      g_realtime = 1;
    } else if (strncmp(argv[k], "log=", 4) == 0) {
      g_log = fopen(argv[k] + 4, "wb");
      if (!g_log) {
        fprintf(stderr, "servodyn-fw: cannot write %s (%s)\n", argv[k] + 4, strerror(errno));
        return 2;
      }
    } else if (strcmp(argv[k], "link=pty") == 0) {
      if (open_link_pty() != 0) return 2;
    } else if (strncmp(argv[k], "link=", 5) == 0) {
      g_link_fd = open(argv[k] + 5, O_RDWR | O_NOCTTY | O_NONBLOCK);
      if (g_link_fd < 0) {
        fprintf(stderr, "servodyn-fw: the host link %s: cannot open (%s)\n", argv[k] + 5, strerror(errno));
        return 2;
      }
    } else if (strncmp(argv[k], "can=", 4) == 0) {
      if (board_posix_can_open(argv[k] + 4) != 0) return 2;
    } else if (strncmp(argv[k], "reply_ms=", 9) == 0) {
      g_reply_ms = atol(argv[k] + 9);
    } else {
      int w = snprintf(g_cmdline + used, sizeof g_cmdline - used, "%s ", argv[k]);
      if (w < 0 || (size_t)w >= sizeof g_cmdline - used) {
        fprintf(stderr, "servodyn-fw: command line too long\n");
        return 2;
      }
      used += (size_t)w;
    }
  }
  g_fd = port ? open(port, O_RDWR | O_NOCTTY | O_NONBLOCK) : -1;
  if (port && g_fd < 0) {
    fprintf(stderr, "servodyn-fw: %s: cannot open (%s)\n", port, strerror(errno));
    return 2;
  }
  if (g_realtime) realtime_setup();
  board_stop(fw_app_main());
}
