/*
 * rig_sim: run the rig_dac firmware on simavr as if it were an Arduino UNO on a serial port.
 *
 *   rig_sim FIRMWARE.elf --log DAC.log [--speed S] [--dac-address 0x60] [--no-dac]
 *
 * - The ATmega328P (16 MHz) UART0 is bridged to a pseudo-terminal made with openpty();
 *   the slave's path is printed on stdout as "pty /dev/pts/N" so the host can open it
 *   with pyserial like a real port.
 * - A small MCP4725 model sits on the simulated I2C bus: it ACKs its address and each
 *   fast-mode write, and logs "dac CYCLE CODE PD" when the DAC register latches (the
 *   ACK of the second data byte). "led CYCLE VALUE" logs the sync LED (PB5, D13).
 *   Every line is flushed as written. CYCLE counts 16 MHz clock cycles since power-up.
 * - Simulated time is paced to the wall clock times --speed (1 = real time) so the
 *   host sees the board at its real rate; while the firmware sleeps we wait on the
 *   pty instead of burning the CPU.
 * - SIGUSR1 resets the AVR (a board reset); SIGTERM/SIGINT end the run.
 *   --no-dac leaves the bus empty (the DAC NACKs: a wiring fault).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_twi.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_irq.h"

static avr_t *avr;
static FILE *log_file;
static int master_fd = -1;
static double speed = 1.0;
static struct timespec wall0;
static volatile sig_atomic_t want_reset, want_exit;
static pid_t parent;

/* ---- host -> AVR bytes (flow-controlled by the UART's XON/XOFF) ---------- */
static uint8_t in_buf[4096];
static size_t in_len, in_pos;
static int uart_xoff;
static avr_irq_t *uart_in_irq;

static void feed_uart(void) {
  while (!uart_xoff && in_pos < in_len) avr_raise_irq(uart_in_irq, in_buf[in_pos++]);
  if (in_pos == in_len) in_pos = in_len = 0;
}

static void read_host(void) {
  if (in_len == 0) {
    ssize_t n = read(master_fd, in_buf, sizeof in_buf);
    if (n > 0) in_len = (size_t)n;
  }
  feed_uart();
}

static void uart_xon_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)value; (void)param;
  uart_xoff = 0;
  feed_uart();
}

static void uart_xoff_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)value; (void)param;
  uart_xoff = 1;
}

/* ---- AVR -> host bytes --------------------------------------------------- */
static void uart_out_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)param;
  uint8_t byte = (uint8_t)value;
  if (write(master_fd, &byte, 1) != 1) fprintf(log_file, "tx-dropped %llu\n", (unsigned long long)avr->cycle);
}

/* ---- MCP4725 on the I2C bus ------------------------------------------------ */
static avr_irq_t *dac_irq;     /* our two IRQs: [TWI_IRQ_INPUT] to the AVR, [TWI_IRQ_OUTPUT] from it */
static uint8_t dac_address = 0x60;
static int dac_present = 1;
static int dac_selected, dac_index;
static uint8_t dac_bytes[3];

static void dac_twi_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)param;
  avr_twi_msg_irq_t v;
  v.u.v = value;
  if (v.u.twi.msg & TWI_COND_STOP) dac_selected = 0;
  if (v.u.twi.msg & TWI_COND_START) {
    dac_selected = dac_present && (v.u.twi.addr >> 1) == dac_address && !(v.u.twi.addr & 1);
    dac_index = 0;
    if (dac_selected) avr_raise_irq(dac_irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, v.u.twi.addr, 1));
  }
  if (dac_selected && (v.u.twi.msg & TWI_COND_WRITE)) {
    avr_raise_irq(dac_irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, v.u.twi.addr, 1));
    if (dac_index < 3) dac_bytes[dac_index] = v.u.twi.data;
    dac_index++;
    /* Fast mode (C2 C1 = 0 0): the output register latches on the second byte. */
    if (dac_index == 2 && (dac_bytes[0] & 0xC0) == 0) {
      unsigned code = ((unsigned)(dac_bytes[0] & 0x0F) << 8) | dac_bytes[1];
      fprintf(log_file, "dac %llu %u %u\n", (unsigned long long)avr->cycle, code, (dac_bytes[0] >> 4) & 3);
      fflush(log_file);
    }
  }
}

static void led_hook(avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)param;
  fprintf(log_file, "led %llu %u\n", (unsigned long long)avr->cycle, value);
  fflush(log_file);
}

/* ---- pacing ---------------------------------------------------------------- */
static double wall_elapsed(void) {
  struct timespec now;
  clock_gettime(CLOCK_MONOTONIC, &now);
  return (double)(now.tv_sec - wall0.tv_sec) + 1e-9 * (double)(now.tv_nsec - wall0.tv_nsec);
}

/* Wait (on the pty, so host bytes are not left waiting) until the wall clock has
 * caught up with simulated cycle `cycle`. */
static void pace_to(avr_cycle_count_t cycle) {
  for (;;) {
    double ahead = (double)cycle / avr->frequency / speed - wall_elapsed();
    int ms = ahead > 0 ? (int)(ahead * 1000.0) : 0;
    struct pollfd pfd = {.fd = master_fd, .events = POLLIN};
    int ready = poll(&pfd, 1, in_len ? 0 : ms);
    if (ready > 0 && (pfd.revents & POLLIN)) read_host();
    if (ms <= 0 || in_len || want_exit || want_reset) return;
  }
}

static void sleep_hook(avr_t *a, avr_cycle_count_t how_long) {
  if (speed > 0) pace_to(a->cycle + how_long);
  else read_host();
}

static void on_signal(int sig) {
  if (sig == SIGUSR1) want_reset = 1;
  else want_exit = 1;
}

int main(int argc, char **argv) {
  const char *elf = NULL, *log_path = NULL;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--log") && i + 1 < argc) log_path = argv[++i];
    else if (!strcmp(argv[i], "--speed") && i + 1 < argc) speed = atof(argv[++i]);
    else if (!strcmp(argv[i], "--dac-address") && i + 1 < argc) dac_address = (uint8_t)strtol(argv[++i], NULL, 0);
    else if (!strcmp(argv[i], "--no-dac")) dac_present = 0;
    else if (!elf) elf = argv[i];
    else { fprintf(stderr, "rig_sim: unexpected argument %s\n", argv[i]); return 2; }
  }
  if (!elf || !log_path) {
    fprintf(stderr, "usage: rig_sim FIRMWARE.elf --log DAC.log [--speed S] [--dac-address A] [--no-dac]\n");
    return 2;
  }
  log_file = fopen(log_path, "w");
  if (!log_file) { perror("rig_sim: log"); return 2; }

  elf_firmware_t fw;
  memset(&fw, 0, sizeof fw);
  if (elf_read_firmware(elf, &fw) != 0) { fprintf(stderr, "rig_sim: cannot read %s\n", elf); return 2; }
  avr = avr_make_mcu_by_name("atmega328p");
  if (!avr) { fprintf(stderr, "rig_sim: simavr has no atmega328p\n"); return 2; }
  avr_init(avr);
  avr_load_firmware(avr, &fw);
  avr->frequency = 16000000;
  avr->log = 1;
  avr->sleep = sleep_hook;

  int slave_fd;
  char name[256];
  if (openpty(&master_fd, &slave_fd, name, NULL, NULL) != 0) { perror("rig_sim: openpty"); return 2; }
  struct termios tio;
  tcgetattr(slave_fd, &tio);
  cfmakeraw(&tio);
  tcsetattr(slave_fd, TCSANOW, &tio);
  /* slave_fd stays open: the master never sees a hang-up while the host reconnects. */
  fcntl(master_fd, F_SETFL, fcntl(master_fd, F_GETFL) | O_NONBLOCK);

  uint32_t flags = 0;
  avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
  flags &= ~AVR_UART_FLAG_STDIO;   /* bytes go to the pty, not to simavr's stdout */
  avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
  uart_in_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out_hook, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook, NULL);

  static const char *dac_names[2] = {"8>mcp4725.out", "32<mcp4725.in"};
  dac_irq = avr_alloc_irq(&avr->irq_pool, 0, 2, dac_names);
  avr_irq_register_notify(dac_irq + TWI_IRQ_OUTPUT, dac_twi_hook, NULL);
  avr_connect_irq(dac_irq + TWI_IRQ_INPUT, avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT));
  avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), dac_irq + TWI_IRQ_OUTPUT);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), IOPORT_IRQ_PIN5), led_hook, NULL);

  signal(SIGUSR1, on_signal);
  signal(SIGTERM, on_signal);
  signal(SIGINT, on_signal);
  parent = getppid();
  fprintf(log_file, "start 0 %u\n", (unsigned)avr->frequency);
  fflush(log_file);
  printf("pty %s\n", name);
  fflush(stdout);
  clock_gettime(CLOCK_MONOTONIC, &wall0);

  unsigned long steps = 0;
  for (;;) {
    int state = avr_run(avr);
    if (state == cpu_Done || state == cpu_Crashed) {
      fprintf(log_file, "crashed %llu %d\n", (unsigned long long)avr->cycle, state);
      fflush(log_file);
      return 1;
    }
    if (++steps % 4096 == 0) {
      if (speed > 0) pace_to(avr->cycle);
      else read_host();
      if (getppid() != parent) want_exit = 1;   /* the host process died: do not linger */
    }
    if (want_reset) {
      want_reset = 0;
      fprintf(log_file, "reset %llu\n", (unsigned long long)avr->cycle);
      fflush(log_file);
      avr_reset(avr);
    }
    if (want_exit) break;
  }
  fprintf(log_file, "exit %llu\n", (unsigned long long)avr->cycle);
  fclose(log_file);
  return 0;
}
