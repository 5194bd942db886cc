// rig_dac.ino: stream DAC codes from the host to an MCP4725 at a fixed sample rate.
//
// Arduino UNO (ATmega328P, 16 MHz) + MCP4725 12-bit I2C DAC (SDA A4, SCL A5),
// sync LED on D13 (PB5, the on-board LED). The protocol is documented in
// rig/README.md and mirrored by rig/protocol.py; the constants marked
// "protocol" below are checked against the Python side by the tests.
//
// Design (why it looks like this):
// - The UNO has 2 KB of RAM, so a drive does not fit whole: the host streams
//   codes into a 256-sample ring buffer and the board grants credits
//   ("you may send samples with index < limit", limit = played + capacity).
// - Timer1 in CTC mode ticks at the sample rate. Its ISR pops one code and
//   starts an interrupt-driven TWI write, so every DAC update lands a fixed
//   latency after its tick whatever the main loop is doing.
// - The main loop parses frames from the UART and sends replies; it sleeps
//   in idle mode between interrupts.
// - Registers only, no Arduino libraries (Serial, Wire): their buffers and
//   ISRs would take RAM and jitter. The sketch builds in the Arduino IDE
//   (which supplies main()) and with plain avr-gcc (standalone_main.cpp).

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdint.h>

#ifndef F_CPU
#define F_CPU 16000000UL
#endif

// ---- protocol --------------------------------------------------------------
#define PROTOCOL_VERSION 1
#define FW_MAJOR 1
#define FW_MINOR 0
#define BAUD 250000UL              // exact at 16 MHz with U2X (UBRR0 = 7)
#define SYNC0 0xA5
#define SYNC1 0x5A
#define MAX_PAYLOAD 64
#define RING_CAPACITY 256          // samples (512 bytes of RAM)
#define MAX_SAMPLES_PER_FRAME 24   // 4-byte index + 24 x 2-byte codes = 52 bytes

// host -> board
#define T_HELLO 0x01
#define T_CONFIG 0x02
#define T_DATA 0x03
#define T_START 0x04
#define T_STOP 0x05
#define T_END 0x06
#define T_STATUS_REQ 0x07
// board -> host
#define T_INFO 0x81
#define T_ACK 0x82
#define T_NAK 0x83
#define T_STATUS 0x84
#define T_UNDERRUN 0x85
#define T_DONE 0x86
#define T_BOOT 0x87
#define T_DAC_ERROR 0x88
// NAK reasons
#define NAK_BAD_CRC 1
#define NAK_BAD_LENGTH 2
#define NAK_OUT_OF_ORDER 3
#define NAK_OVERFLOW 4
#define NAK_BAD_CODE 5
#define NAK_BAD_STATE 6
#define NAK_UNKNOWN_TYPE 7
// states
#define S_IDLE 0
#define S_RUNNING 1
#define S_DRAINING 2
#define S_DONE 3
// ---- end protocol ----------------------------------------------------------

#define LED_BIT PB5
#define RX_RING 128                // bytes, power of two

// Playback state shared with the timer ISR (volatile; 32-bit reads under cli).
static volatile uint16_t ring[RING_CAPACITY];
static volatile uint32_t played;        // samples sent to the DAC since START
static volatile uint32_t ticks;         // timer periods since START (played + missed)
static volatile uint32_t written;       // samples received (next index expected)
static volatile uint32_t end_index;     // total samples, valid once END arrived
static volatile uint8_t state = S_IDLE;
static volatile uint16_t underrun_ticks;    // ticks with no sample to play
static volatile uint8_t starving;           // inside an underrun episode
static volatile uint32_t underrun_index;    // first missing sample of the episode
static volatile uint16_t underrun_length;   // ticks missed in the episode
static volatile uint32_t underrun_tick;     // the tick at which that sample finally played
static volatile uint8_t ended;              // END arrived: stop after end_index samples
static volatile uint8_t underrun_report;    // an episode ended: tell the host
static volatile uint8_t status_due;
static volatile uint8_t done_due;
static volatile uint16_t dac_errors;
static volatile uint8_t dac_error_report;
static volatile uint8_t dac_error_status;
static uint16_t bad_frames;
static uint16_t status_every = 8;       // ticks between STATUS reports
static uint16_t sync_samples = 15;      // LED on while playing samples [0, sync_samples)
static uint16_t idle_code = 2048;       // the code for 0 V through the amplifier
static uint8_t dac_addr = 0x60;         // MCP4725 7-bit address (A0 low)
static uint8_t prescale_bits = _BV(CS11) | _BV(CS10);  // /64
static uint16_t top = 8332;             // OCR1A: period = (top + 1) * prescale / F_CPU

// ---- TWI: one 3-byte MCP4725 fast-mode write, interrupt driven -------------
static volatile uint8_t twi_bytes[3];
static volatile uint8_t twi_index;
static volatile uint8_t twi_busy;

static void twi_write_code(uint16_t code) {
  // Fast-mode write: [addr|W] [0 0 PD1 PD0 D11..D8] [D7..D0]; PD = 00 (on).
  twi_bytes[0] = (uint8_t)(dac_addr << 1);
  twi_bytes[1] = (uint8_t)((code >> 8) & 0x0F);
  twi_bytes[2] = (uint8_t)(code & 0xFF);
  twi_index = 0;
  twi_busy = 1;
  TWCR = _BV(TWINT) | _BV(TWSTA) | _BV(TWEN) | _BV(TWIE);
}

ISR(TWI_vect) {
  uint8_t status = TWSR & 0xF8;
  if (status == 0x08 || status == 0x18 || status == 0x28) {  // START sent, SLA+W ACKed, data ACKed
    if (twi_index < 3) {
      TWDR = twi_bytes[twi_index++];
      TWCR = _BV(TWINT) | _BV(TWEN) | _BV(TWIE);
      return;
    }
    TWCR = _BV(TWINT) | _BV(TWSTO) | _BV(TWEN);  // done: STOP, the DAC has latched
  } else {                                        // NACK or bus error: give up on this sample
    TWCR = _BV(TWINT) | _BV(TWSTO) | _BV(TWEN);
    dac_errors++;
    dac_error_status = status;
    dac_error_report = 1;
  }
  twi_busy = 0;
}

// ---- Timer1: one tick per sample --------------------------------------------
ISR(TIMER1_COMPA_vect) {
  uint32_t index = played;
  if (index == sync_samples) PORTB &= ~_BV(LED_BIT);
  if (index != written) {                       // a sample is waiting
    if (index == 0) PORTB |= _BV(LED_BIT);      // sync: sample 0 is on the LED edge
    if (twi_busy) {                             // previous write still on the bus
      dac_errors++;
      dac_error_status = 0xFF;
      dac_error_report = 1;
    } else {
      twi_write_code(ring[(uint8_t)index]);
    }
    played = index + 1;
    if (starving) {                             // the episode ends with this sample
      starving = 0;
      underrun_tick = ticks;
      underrun_report = 1;
    }
    if (ended && played == end_index) {
      TCCR1B = 0;                               // stop: the last code stays on the DAC
      state = S_DONE;
      done_due = 1;
    }
  } else if (ended && index == end_index) {
    TCCR1B = 0;
    state = S_DONE;
    done_due = 1;
  } else {                                      // underrun: hold the last code
    underrun_ticks++;
    if (!starving) {
      starving = 1;
      underrun_index = index;
      underrun_length = 0;
    }
    underrun_length++;
  }
  ticks++;
  if (ticks % status_every == 0) status_due = 1;
}

// ---- UART -------------------------------------------------------------------
static volatile uint8_t rx_buf[RX_RING];
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t rx_overflows;

ISR(USART_RX_vect) {
  uint8_t byte = UDR0;
  uint8_t next = (rx_head + 1) & (RX_RING - 1);
  if (next == rx_tail) {
    rx_overflows++;                             // dropped: the frame's CRC will fail
    return;
  }
  rx_buf[rx_head] = byte;
  rx_head = next;
}

static void uart_init(void) {
  UCSR0A = _BV(U2X0);
  UBRR0 = (uint16_t)(F_CPU / (8UL * BAUD) - 1);
  UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
  UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);           // 8N1
}

static void uart_put(uint8_t byte) {
  while (!(UCSR0A & _BV(UDRE0))) {
  }
  UDR0 = byte;
}

// CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor.
static uint16_t crc16_update(uint16_t crc, uint8_t byte) {
  crc ^= (uint16_t)byte << 8;
  for (uint8_t i = 0; i < 8; i++) crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
  return crc;
}

static uint8_t tx_seq;

static void send_frame(uint8_t type, const uint8_t *payload, uint8_t len) {
  uint16_t crc = 0xFFFF;
  uart_put(SYNC0);
  uart_put(SYNC1);
  uint8_t header[3] = {type, tx_seq++, len};
  for (uint8_t i = 0; i < 3; i++) {
    uart_put(header[i]);
    crc = crc16_update(crc, header[i]);
  }
  for (uint8_t i = 0; i < len; i++) {
    uart_put(payload[i]);
    crc = crc16_update(crc, payload[i]);
  }
  uart_put((uint8_t)(crc & 0xFF));              // little-endian, like every field
  uart_put((uint8_t)(crc >> 8));
}

static uint8_t *put16(uint8_t *p, uint16_t v) {
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
  return p + 2;
}

static uint8_t *put32(uint8_t *p, uint32_t v) {
  p = put16(p, (uint16_t)v);
  return put16(p, (uint16_t)(v >> 16));
}

static uint16_t get16(const uint8_t *p) { return (uint16_t)p[0] | ((uint16_t)p[1] << 8); }

static uint32_t get32(const uint8_t *p) { return (uint32_t)get16(p) | ((uint32_t)get16(p + 2) << 16); }

static uint32_t read32(volatile uint32_t *v) {
  uint8_t sreg = SREG;
  cli();
  uint32_t value = *v;
  SREG = sreg;
  return value;
}

// ---- replies ----------------------------------------------------------------
static void send_ack(uint8_t type) {
  uint8_t p[9], *q = p;
  *q++ = type;
  q = put32(q, read32(&written));
  put32(q, read32(&played) + RING_CAPACITY);    // credit limit
  send_frame(T_ACK, p, 9);
}

static void send_nak(uint8_t reason, uint8_t type) {
  uint8_t p[6], *q = p;
  *q++ = reason;
  *q++ = type;
  put32(q, read32(&written));
  bad_frames++;
  send_frame(T_NAK, p, 6);
}

static void send_status(void) {
  uint8_t p[24], *q = p;
  cli();
  uint32_t s_played = played, s_ticks = ticks, s_written = written;
  uint16_t s_tcnt = TCNT1, s_under = underrun_ticks, s_dac = dac_errors;
  uint8_t s_state = state;
  sei();
  *q++ = s_state;
  q = put32(q, s_played);
  q = put32(q, s_ticks);
  q = put16(q, s_tcnt);                         // timer counts into the current tick
  q = put16(q, (uint16_t)(s_written - s_played));   // buffer level
  q = put16(q, s_under);
  q = put16(q, bad_frames);
  q = put16(q, s_dac);
  put32(q, s_played + RING_CAPACITY);
  send_frame(T_STATUS, p, 23);
}

static void send_info(void) {
  uint8_t p[10], *q = p;
  *q++ = PROTOCOL_VERSION;
  *q++ = FW_MAJOR;
  *q++ = FW_MINOR;
  q = put16(q, RING_CAPACITY);
  q = put32(q, F_CPU);
  *q++ = MAX_SAMPLES_PER_FRAME;
  send_frame(T_INFO, p, 10);
}

// ---- frame handling -----------------------------------------------------------
static void idle_dac(void) {
  TCCR1B = 0;
  PORTB &= ~_BV(LED_BIT);
  while (twi_busy) {
  }
  twi_write_code(idle_code);
}

static void handle_frame(uint8_t type, const uint8_t *p, uint8_t len) {
  switch (type) {
    case T_HELLO:
      send_info();
      return;
    case T_STATUS_REQ:
      send_status();
      return;
    case T_CONFIG:                              // prescale code, top, idle code, sync, status, addr
      if (state == S_RUNNING || state == S_DRAINING) { send_nak(NAK_BAD_STATE, type); return; }
      if (len != 10 || p[0] < 1 || p[0] > 5 || get16(p + 3) > 4095 || get16(p + 7) == 0) {
        send_nak(NAK_BAD_LENGTH, type);
        return;
      }
      prescale_bits = p[0];                     // CS12..CS10 value: 1=/1 2=/8 3=/64 4=/256 5=/1024
      top = get16(p + 1);
      idle_code = get16(p + 3);
      sync_samples = get16(p + 5);
      status_every = get16(p + 7);
      dac_addr = p[9] & 0x7F;
      cli();
      played = ticks = written = end_index = 0;
      ended = 0;
      underrun_ticks = dac_errors = 0;
      starving = underrun_report = status_due = done_due = dac_error_report = 0;
      sei();
      bad_frames = 0;
      state = S_IDLE;
      idle_dac();
      send_ack(type);
      return;
    case T_DATA: {
      if (state != S_IDLE && state != S_RUNNING) { send_nak(NAK_BAD_STATE, type); return; }
      if (len < 6 || (len - 4) % 2 != 0 || (len - 4) / 2 > MAX_SAMPLES_PER_FRAME) {
        send_nak(NAK_BAD_LENGTH, type);
        return;
      }
      uint8_t count = (uint8_t)((len - 4) / 2);
      uint32_t first = get32(p);
      uint32_t next = read32(&written);
      if (first != next) { send_nak(NAK_OUT_OF_ORDER, type); return; }
      if (first + count > read32(&played) + RING_CAPACITY) { send_nak(NAK_OVERFLOW, type); return; }
      for (uint8_t i = 0; i < count; i++) {
        if (get16(p + 4 + 2 * i) > 4095) { send_nak(NAK_BAD_CODE, type); return; }
      }
      for (uint8_t i = 0; i < count; i++) ring[(uint8_t)(first + i)] = get16(p + 4 + 2 * i);
      cli();
      written = first + count;                  // publish after the codes are in place
      sei();
      send_ack(type);
      return;
    }
    case T_START:
      if (state != S_IDLE) { send_nak(NAK_BAD_STATE, type); return; }
      state = ended ? S_DRAINING : S_RUNNING;
      send_ack(type);                           // before the first tick: the host times from here
      TCNT1 = 0;
      OCR1A = top;
      TIFR1 = _BV(OCF1A);
      TIMSK1 = _BV(OCIE1A);
      TCCR1A = 0;
      TCCR1B = _BV(WGM12) | prescale_bits;      // CTC; sample 0 plays at the first match
      return;
    case T_END:
      if (len != 4) { send_nak(NAK_BAD_LENGTH, type); return; }
      if (state != S_RUNNING && state != S_IDLE) { send_nak(NAK_BAD_STATE, type); return; }
      if (get32(p) != read32(&written)) { send_nak(NAK_OUT_OF_ORDER, type); return; }
      cli();
      end_index = get32(p);
      ended = 1;
      if (state == S_RUNNING) state = S_DRAINING;
      sei();
      send_ack(type);
      return;
    case T_STOP:
      idle_dac();
      state = S_IDLE;
      cli();
      played = ticks = written = end_index = 0;
      ended = 0;
      sei();
      send_ack(type);
      return;
    default:
      send_nak(NAK_UNKNOWN_TYPE, type);
  }
}

// Frame parser: SYNC0 SYNC1 type seq len payload[len] crc_lo crc_hi.
static uint8_t frame[MAX_PAYLOAD + 3];
static uint8_t parse_state, parse_pos, parse_len;
static uint16_t parse_crc;

static void parse_byte(uint8_t byte) {
  switch (parse_state) {
    case 0:
      if (byte == SYNC0) parse_state = 1;
      return;
    case 1:
      parse_state = (byte == SYNC1) ? 2 : (byte == SYNC0 ? 1 : 0);
      parse_pos = 0;
      parse_crc = 0xFFFF;
      return;
    case 2:                                     // type, seq, len
      frame[parse_pos++] = byte;
      parse_crc = crc16_update(parse_crc, byte);
      if (parse_pos == 3) {
        parse_len = byte;
        if (parse_len > MAX_PAYLOAD) {          // cannot be a frame: resynchronise
          parse_state = 0;
          send_nak(NAK_BAD_LENGTH, frame[0]);
          return;
        }
        parse_state = parse_len ? 3 : 4;
      }
      return;
    case 3:                                     // payload
      frame[parse_pos++] = byte;
      parse_crc = crc16_update(parse_crc, byte);
      if (parse_pos == 3 + parse_len) parse_state = 4;
      return;
    case 4:                                     // crc low byte
      parse_crc ^= byte;
      parse_state = 5;
      return;
    case 5:                                     // crc high byte
      parse_state = 0;
      if ((parse_crc ^ ((uint16_t)byte << 8)) != 0) {
        send_nak(NAK_BAD_CRC, frame[0]);
        return;
      }
      handle_frame(frame[0], frame + 3, parse_len);
      return;
  }
}

// ---- setup / loop --------------------------------------------------------------
void setup(void) {
  uint8_t cause = MCUSR;
  MCUSR = 0;
  DDRB |= _BV(LED_BIT);
  PORTB &= ~_BV(LED_BIT);
  PORTC |= _BV(PC4) | _BV(PC5);                 // weak pull-ups on SDA/SCL (boards add 4.7k)
  TWSR = 0;                                     // TWI prescaler 1
  TWBR = (uint8_t)((F_CPU / 400000UL - 16) / 2);  // 400 kHz fast mode
  uart_init();
  sei();
  twi_write_code(idle_code);                    // 0 V on the strip from power-up
  uint8_t p[2] = {cause, PROTOCOL_VERSION};
  send_frame(T_BOOT, p, 2);
}

void loop(void) {
  while (rx_tail != rx_head) {
    uint8_t byte = rx_buf[rx_tail];
    rx_tail = (rx_tail + 1) & (RX_RING - 1);
    parse_byte(byte);
  }
  if (underrun_report) {
    uint8_t p[10], *q = p;
    cli();
    uint32_t index = underrun_index;
    uint16_t length = underrun_length;
    uint32_t tick = underrun_tick;
    underrun_report = 0;
    sei();
    q = put32(q, index);                        // first sample that came late
    q = put16(q, length);                       // ticks it came late by
    put32(q, tick);                             // the tick at which it played
    send_frame(T_UNDERRUN, p, 10);
  }
  if (dac_error_report) {
    dac_error_report = 0;
    uint8_t p[7], *q = p;
    q = put32(q, read32(&ticks));
    *q++ = dac_error_status;
    put16(q, dac_errors);
    send_frame(T_DAC_ERROR, p, 7);
  }
  if (status_due) {
    status_due = 0;
    send_status();
  }
  if (done_due) {
    done_due = 0;
    uint8_t p[12], *q = p;
    q = put32(q, read32(&played));
    q = put32(q, read32(&ticks));
    q = put16(q, underrun_ticks);
    put16(q, bad_frames);
    send_frame(T_DONE, p, 12);
  }
  cli();                                        // sleep only if nothing arrived meanwhile
  if (rx_tail == rx_head && !status_due && !done_due && !underrun_report && !dac_error_report) {
    set_sleep_mode(SLEEP_MODE_IDLE);
    sleep_enable();
    sei();
    sleep_cpu();
    sleep_disable();
  }
  sei();
}
