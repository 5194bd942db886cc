// main() for building rig_dac.ino with plain avr-gcc (the Arduino IDE supplies its own).
void setup(void);
void loop(void);

int main(void) {
  setup();
  for (;;) loop();
}
