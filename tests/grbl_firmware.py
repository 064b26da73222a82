"""The real GRBL 1.1h firmware, compiled for the host with grbl-sim, as a test peer on a pseudo-terminal.

`build_firmware()` unpacks tests/vendor/grbl/grbl-1.1h-with-grbl-sim.tar.gz (its README gives the provenance,
the licence and why each patch is there), applies `PATCHES`, adds `NEW_FILES` (rig_hw.c: the rail, the carriage,
its switches, a cheaper clock) and builds `grbl_sim.exe` once per hash of all that, in
`$XDG_CACHE_HOME/rig-tests/grbl-<hash>/` (~/.cache when unset); concurrent pytest-xdist workers wait on a file
lock, and the build goes into a temporary folder renamed into place. `require_firmware()` skips the calling test
with a one-line reason when there is no C compiler (cc/gcc) or no `make`.

`GrblFirmware(workdir, ...)` runs it in `workdir` (EEPROM.DAT and CARRIAGE.TXT live there), waits for the
start-up burst, writes the settings asked for, power-cycles it, and bridges its pipes to a pseudo-terminal
(`.port`, opened with pyserial as one would open /dev/ttyUSB0), with faults on the bridge: garbled status
reports, a held reply, a dropped byte, a stalled link, an unplugged controller (`kill()`) and a re-enumerated
one (`restart()`).

What the firmware does on a host (2 AMD EPYC cores; "sim time" is grbl-sim's 16 MHz tick count, see `%`):

- Start-up: grbl-sim leaves its serial port alone for the first second of sim time, so nothing comes for ~1.0 s
  after exec; then, on a fresh folder, `error:7` (EEPROM read fail), the stock settings (`$0=10` ... `$132=200.000`)
  and "\r\n" + banner at once. With an EEPROM.DAT: only "\r\n" + banner, plus `[MSG:'$H'|'$X' to unlock]` if
  $22=1 (homing on locks a power-up in Alarm; a soft reset does not). Input that arrives before GRBL's main
  loop starts (and during any reset) is thrown away: main.c clears the RX buffer on every (re)start.
- Stock grbl-sim busy-waits: its hardware thread runs every 16 MHz tick and polls stdin every 66 ticks with four
  system calls, one core at 100 % however idle GRBL is, and it falls behind real time when the host is busy:
  0.56-0.66x with two busy processes on the 2 cores (GRBL's moves then take up to 1.8x as long as planned).
  GRBL's own thread spins in every wait (12 % of a core idle, 100 % in a feed hold, and for the whole first
  second of a fresh start, its settings dump waiting for the serial port). Patched (`sim-sleep`,
  `poll-stdin-cheaply`, `grbl-thread-sleep`): 0.04 cores idle (GRBL's thread sleeps 1 ms a pass), ~0.08 moving
  or homing, 0.05 in a hold, 0.1 s of CPU for a fresh start, and sim time within 0.1 % of real time, loaded or not (tests/vendor/grbl/README.md
  has the table). The simulator runs its ticks in batches of up to 1 ms of sim time (an incoming byte or a
  reply GRBL queues ends a batch at once), so GRBL's main program sees steps and switches land in such batches.
- grbl-sim runs GRBL's main program and its interrupts in two threads. Stock, they shared SREG, and one could
  write back the other's cleared I bit: interrupts off for good, a move frozen in Run while the reports still
  came (~1 move in 70 with a '?' every 20 ms, within seconds under a '?' flood); and GRBL's serial rings, as
  compiled, could hand over a byte before it was stored: a stale character in a reply. Patched
  (`sreg-per-thread`, `ring-buffer-order`): neither, in 600 moves polled every 20 ms, loaded or not.
- `%` makes grbl-sim print `<ticks> <sim seconds>\n` (a bare "\n", not GRBL's "\r\n") and is then handed to
  GRBL as an ordinary character, which ends up in the next line (`%` alone: error:1, or error:9 in Alarm;
  `%$$`: error:1). The bridge never forwards that line to the client; `sim_clock()` asks for it.
- Ctrl-F (0x06), a 0xFF byte or EOF on stdin make grbl-sim exit, but only once GRBL is Idle, Alarm or Check
  (a move finishes first; in a Hold or Sleep, never). A real GRBL ignores 0x06 and 0xFF, so the bridge keeps
  them from the firmware (they stay in `.sent`); with the `poll-stdin-cheaply` patch EOF (the harness is gone)
  ends it at once, so no firmware outlives a killed pytest. NUL never reaches GRBL (the sim's poll uses 0 for
  "nothing"); GRBL would drop it anyway.
- GRBL's delays are real sleeps in grbl-sim, not sim time: G4, the $26 homing debounce, the $1 step idle delay
  (run in the hardware thread after each move, the serial port deaf meanwhile) and the 500 ms after every
  ALARM:N report (report.c), during which GRBL answers nothing.
- Stock grbl-sim ties every input pin low, which GRBL reads as all limits, probe, reset, feed hold and cycle
  start triggered (`Pn:PXYZRHS`); `$H` then fails with ALARM:8. rig_hw.c wires the pins as on a real one-axis
  stage instead; stock GRBL homes Z first, so the build homes X alone (`home-x-only`).

What GRBL 1.1h itself does that a driver must expect (seen through this harness, and read in its source):

- Feed hold `!`: `Hold:1` while decelerating, `Hold:0` once stopped. `~` during `Hold:1` is ignored: only a `~`
  after `Hold:0` resumes. `!` when Idle gives `Hold:0` too (a hold with nothing to hold; `~` returns to Idle).
  Lines sent during a hold are buffered, not answered, until the resume.
- Soft reset Ctrl-X: in Idle or `Hold:0` (even after a hold mid-move), no alarm, position kept, Idle after the
  banner. During motion or `Hold:1`: ALARM:3, 0.5 s of silence, the banner and `[MSG:'$H'|'$X' to unlock]`,
  state Alarm (position as counted: the sim loses no steps). After a reset the feed rate is gone: `G1` with no
  F gives error:22.
- ALARM:2 (soft limit; a target beyond the travel, checked when the line is planned, in Idle too) and ALARM:1
  (hard limit, $21=1; leaving a switch trips it as well as reaching one, any pin change does): the alarm, then
  0.5 s later `[MSG:Reset to continue]`, then GRBL answers nothing at all, not even `?`, until Ctrl-X; a Ctrl-X
  sent during that 0.5 s is cleared and lost. The line that caused ALARM:2 gets its `ok` only after the reset.
  After a reset with a switch still closed and $21=1: `[MSG:Check Limits]` and Alarm, `Pn:X` in the reports.
- `$SLP`: `ok`, then `[MSG:Sleeping]`, state `Sleep`; every line after it goes unanswered; only Ctrl-X wakes it,
  into Alarm (`[MSG:'$H'|'$X' to unlock]`).
- Status reports: `WCO:` comes in the first report after a (re)start and then every 10th report when idle
  (every 30th when busy), and at once after a change of offsets (G92, G10); `Ov:` in the report after each
  `WCO:` one and then every 10th (20th busy) and after an override change. `Pn:` only while a pin is active.
  GRBL answers no `?` during `$H`.
- `$J=` beyond the soft limits: error:15, no alarm. `$C` outside Idle: error:8.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import re
import select
import shutil
import signal
import subprocess
import tarfile
import tempfile
import threading
import time
import tty
import weakref
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, NamedTuple

HERE = Path(__file__).resolve().parent
TARBALL = HERE / "vendor" / "grbl" / "grbl-1.1h-with-grbl-sim.tar.gz"
EXE_NAME = "grbl_sim.exe"
# modern gcc needs -fcommon (grbl-sim defines globals in headers); -ffp-contract=off: GRBL's float arithmetic (the
# planner, printFloat's rounding) as on x86-64, where the golden transcripts were recorded: GCC fuses a * b + c into
# one operation on processors that have one (aarch64) unless told not to, which can move a printed position by a digit
MAKE_FLAGS = "-g -O2 -fcommon -ffp-contract=off"
BANNER = "Grbl 1.1h ['$' for help]"
CARRIAGE_FILE = "CARRIAGE.TXT"


# ---------------------------------------------------------------------------------------------------------------
# The patches: anchored text replacements, each failing loudly when its anchor is not found exactly once.
# tests/vendor/grbl/README.md says why each one is there; keep the two in step.
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Patch:
    name: str
    path: str  # relative to the tarball's grbl/ folder
    anchor: str
    replacement: str


PATCHES: tuple[Patch, ...] = (
    Patch(
        "unbuffered-stdio", "grbl-sim/main.c",
        "  //setvbuf(stdout, NULL, _IONBF, 1);\n",
        "  setvbuf(stdout, NULL, _IONBF, 0); setvbuf(stdin, NULL, _IONBF, 0); // rig patch: replies leave at once,\n"
        "  // and select() on fd 0 sees every byte (a buffered stdin hides bytes that stdio already read)\n",
    ),
    Patch(
        "eeprom-flush", "grbl-sim/avr/eeprom.c",
        "  fputc(new_value, fp);\n",
        "  fputc(new_value, fp);\n"
        "  fflush(fp); // rig patch: a real EEPROM keeps a written byte; a killed process must keep its settings\n",
    ),
    Patch(
        "limit-switches: build rig_hw.c", "grbl-sim/Makefile",
        "SIM_OBJECTS = main.o simulator.o serial.o ",
        "SIM_OBJECTS = rig_hw.o main.o simulator.o serial.o ",
    ),
    Patch(
        "limit-switches: declare", "grbl-sim/grbl_interface.c",
        "void grbl_app_init(void){\n",
        "void rig_hw_init(void); // rig patch: the rail, its carriage and switches (rig_hw.c)\n"
        "void rig_hw_tick(void);\n\n"
        "void grbl_app_init(void){\n",
    ),
    Patch(
        "limit-switches: init", "grbl-sim/grbl_interface.c",
        "  pc_vect = interrupt_LIMIT_INT_vect;\n",
        "  pc_vect = interrupt_LIMIT_INT_vect;\n"
        "  rig_hw_init(); // rig patch: input pins as wired, the carriage where the rail left it\n",
    ),
    Patch(
        "limit-switches: tick", "grbl-sim/grbl_interface.c",
        "  //TODO:\n  //  set limit pins based on position,\n",
        "  rig_hw_tick(); // rig patch: follow the X step pulses, set the X limit pin from the carriage position\n"
        "  //TODO:\n  //  set limit pins based on position,\n",
    ),
    Patch(
        "home-x-only", "config.h",
        "#define HOMING_CYCLE_0 (1<<Z_AXIS)                // REQUIRED: First move Z to clear workspace.\n"
        "#define HOMING_CYCLE_1 ((1<<X_AXIS)|(1<<Y_AXIS))  // OPTIONAL: Then move X,Y at the same time.\n",
        "// rig patch: a one-axis linear stage homes X alone (stock: Z first, then X and Y, which fails with\n"
        "// ALARM:9 after a 1.5*$132 search on a machine that has no Z switch)\n"
        "#define HOMING_CYCLE_0 (1<<X_AXIS)\n",
    ),
    Patch(
        "tx-race", "grbl-sim/serial.c",
        "void simulate_write_interrupt(){\n"
        "  while (UCSR0B & (1<<UDRIE0)){\n",
        "// rig patch: on the AVR the UDRE interrupt and serial_write() never interleave; here they run in two\n"
        "// threads, and the interrupt could clear UDRIE0 just after serial_write() queued a byte and set it (the\n"
        "// byte then waited for the next write: a reply held until the client sent something), or see UDRIE0 set\n"
        "// on an empty buffer and send stale bytes. Send exactly what is queued.\n"
        "extern uint8_t serial_tx_buffer_head;\n"
        "extern volatile uint8_t serial_tx_buffer_tail;\n"
        "void simulate_write_interrupt(){\n"
        "  while (serial_tx_buffer_tail != *(volatile uint8_t *)&serial_tx_buffer_head){\n"
        "    __atomic_thread_fence(__ATOMIC_ACQUIRE); // the byte was stored before the head that shows it\n",
    ),
    Patch(
        "sim-sleep: declare", "grbl-sim/simulator.c",
        "//runs the hardware simulator at the desired rate until sim.exit is set\n",
        "void rig_hw_catch_up(uint64_t until); // rig patch (rig_hw.c)\n"
        "void rig_hw_skip(uint64_t until, uint64_t *next_byte_tick);\n"
        "void rig_hw_sleep(uint64_t next_byte_tick);\n\n"
        "//runs the hardware simulator at the desired rate until sim.exit is set\n",
    ),
    Patch(
        "sim-sleep: skip uneventful ticks", "grbl-sim/simulator.c",
        "   while (sim.masterclock < simulated_ticks){\n",
        "   rig_hw_catch_up(simulated_ticks); // rig patch: no poll of stdin while it is known to be empty\n"
        "   while (sim.masterclock < simulated_ticks){\n"
        "    // rig patch: skip the ticks in which no interrupt can fire and the serial port has nothing to do\n"
        "    rig_hw_skip(simulated_ticks, &next_byte_tick);\n",
    ),
    Patch(
        "sim-sleep: sleep until something must happen", "grbl-sim/simulator.c",
        "   platform_sleep(0); //yield\n",
        "   // rig patch: instead of yielding (~16000 wake-ups a second while moving), sleep until a byte arrives on\n"
        "   // stdin, GRBL queues one to send, or 1 ms has passed; the ticks meanwhile are then run at once\n"
        "   rig_hw_sleep(next_byte_tick);\n",
    ),
    Patch(
        "sim-sleep: wait for room to send", "serial.c",
        "    if (sys_rt_exec_state & EXEC_RESET) { return; } // Only check for abort to avoid an endless loop.\n",
        "    if (sys_rt_exec_state & EXEC_RESET) { return; } // Only check for abort to avoid an endless loop.\n"
        "    { void platform_sleep(long microsec); platform_sleep(200); } // rig patch: the TX ring is full; sleep\n"
        "    // instead of spinning a core (for the whole first second of a fresh start, whose settings dump fills it\n"
        "    // while grbl-sim sends nothing yet)\n",
    ),
    Patch(
        "sim-sleep: wake on output", "serial.c",
        "  // Enable Data Register Empty Interrupt to make sure tx-streaming is running\n"
        "  UCSR0B |=  (1 << UDRIE0);\n",
        "  // Enable Data Register Empty Interrupt to make sure tx-streaming is running\n"
        "  UCSR0B |=  (1 << UDRIE0);\n"
        "  { void rig_tx_kick(void); rig_tx_kick(); } // rig patch: wake the simulator if it sleeps (rig_hw.c)\n",
    ),
    Patch(
        "grbl-thread-sleep: realtime loop", "protocol.c",
        "void protocol_exec_rt_system()\n{\n",
        "void platform_sleep(long microsec); // rig patch: GRBL's waiting loops (idle, buffer sync, full planner,\n"
        "// feed hold, probing) all pass here; on the host each pass sleeps 1 ms instead of spinning a core (the\n"
        "// simulator runs its ticks in batches of up to 1 ms; the stepper's segment buffer holds ~60 ms of motion)\n"
        "extern volatile uint8_t rig_isr_active; // rig_hw.c\n"
        "void protocol_exec_rt_system()\n{\n"
        "  platform_sleep(1000);\n"
        "  while (rig_isr_active) { platform_sleep(50); } // an interrupt from rig_hw.c is running: on the AVR the\n"
        "  // main program would be frozen meanwhile (the limit interrupt sets ALARM:3 in mc_reset(), sleeps $1 ms in\n"
        "  // st_go_idle(), then sets ALARM:1: GRBL must not see the 3)\n",
    ),
    Patch(
        "grbl-thread-sleep: serial_read", "grbl-sim/serial.c",
        "uint8_t serial_read() {\n  platform_sleep(0);\n",
        "uint8_t serial_read() {\n"
        "  // rig patch: no sleep per byte read (~55 us each: the timer slack); the main loop sleeps in\n"
        "  // protocol_exec_rt_system() when there is nothing to read\n",
    ),
    Patch(
        "grbl-thread-sleep: homing loop", "limits.c",
        "      st_prep_buffer(); // Check and prep segment buffer. NOTE: Should take no longer than 200us.\n",
        "      { void platform_sleep(long microsec); platform_sleep(200); } // rig patch: poll the switches every\n"
        "      // ~250 us (the sleep's slack included) instead of spinning a core; the simulator moves the carriage in\n"
        "      // batches of up to 1 ms (rig_hw_sleep), so polling faster would see nothing new\n"
        "      st_prep_buffer(); // Check and prep segment buffer. NOTE: Should take no longer than 200us.\n",
    ),
    Patch(
        "poll-stdin-cheaply", "grbl-sim/platform_LINUX.c",
        "uint8_t platform_poll_stdin() {\n"
        "  uint8_t char_in=0;\n"
        "  enable_kbhit(1);\n"
        "  if ( kbhit()) {\n"
        "\t char_in = getchar();\n"
        "  }\n"
        "  enable_kbhit(0);\n"
        "  return char_in;\n"
        "}\n",
        "// rig patch: terminal calls only on a terminal (they fail on a pipe, 2 wasted system calls each); after\n"
        "// an empty poll the next one waits 50 us of sim time (stock: every 66 ticks, 4 us, 4 system calls); EOF\n"
        "// (the harness is gone) ends the simulation at once, whatever GRBL is doing (stock: EOF was read again on\n"
        "// every poll, which slowed the sim to a crawl, and the sim waited for GRBL to be idle, forever in a hold)\n"
        "#include \"simulator.h\"\n"
        "extern uint64_t rig_next_poll; // rig_hw.c\n"
        "uint8_t platform_poll_stdin() {\n"
        "  static int tty = -1, eof = 0;\n"
        "  uint8_t char_in=0;\n"
        "  if (eof || sim.masterclock < rig_next_poll) { return 0; }\n"
        "  if (tty < 0) { tty = isatty(STDIN_FILENO); }\n"
        "  if (tty) { enable_kbhit(1); }\n"
        "  if ( kbhit()) {\n"
        "\t int c = getchar();\n"
        "\t if (c == EOF) { eof = 1; sim.exit = exit_OK; c = 0; }\n"
        "\t char_in = c;\n"
        "  }\n"
        "  if (tty) { enable_kbhit(0); }\n"
        "  if (!char_in) { rig_next_poll = sim.masterclock + F_CPU/20000; }\n"
        "  return char_in;\n"
        "}\n",
    ),
    Patch(
        "ring-buffer-order: tx", "serial.c",
        "  serial_tx_buffer[serial_tx_buffer_head] = data;\n  serial_tx_buffer_head = next_head;\n",
        "  serial_tx_buffer[serial_tx_buffer_head] = data;\n"
        "  // rig patch: the byte before the head that hands it over. gcc -O2 stored the head first (the two are\n"
        "  // plain variables), and the other thread, seeing the new head, could send the byte that was there\n"
        "  // before: a stale character in a reply (<Run|MPos:14.07200.000,...>). Same for the RX ring below.\n"
        "  __atomic_thread_fence(__ATOMIC_RELEASE);\n"
        "  serial_tx_buffer_head = next_head;\n",
    ),
    Patch(
        "ring-buffer-order: rx", "serial.c",
        "          serial_rx_buffer[serial_rx_buffer_head] = data;\n          serial_rx_buffer_head = next_head;\n",
        "          serial_rx_buffer[serial_rx_buffer_head] = data;\n"
        "          __atomic_thread_fence(__ATOMIC_RELEASE); // rig patch: the byte before the head (see serial_write)\n"
        "          serial_rx_buffer_head = next_head;\n",
    ),
    Patch(
        "ring-buffer-order: rx read", "serial.c",
        "    uint8_t data = serial_rx_buffer[tail];\n",
        "    __atomic_thread_fence(__ATOMIC_ACQUIRE); // rig patch: read the byte after the head that showed it,\n"
        "    uint8_t data = serial_rx_buffer[tail];\n"
        "    __atomic_thread_fence(__ATOMIC_RELEASE); // and before the tail that frees its slot\n",
    ),
    Patch(
        "sreg-per-thread: SREG", "grbl-sim/avr/io.h",
        "#define SREG io.sreg\n",
        "// rig patch: GRBL's main program and its interrupts run in two threads; each sees its own SREG (see\n"
        "// sim_sreg() in interrupt.c). The I bit that gates the interrupts is the main program's, io.sreg.\n"
        "volatile uint8_t *sim_sreg(void);\n"
        "#define SREG (*sim_sreg())\n",
    ),
    Patch(
        "sreg-per-thread: sei/cli", "grbl-sim/avr/interrupt.c",
        "void sei() {io.sreg|=SEI;}\nvoid cli() {io.sreg&=~SEI;}\n",
        "// rig patch: one SREG shared by two threads lost the I bit for good. GRBL guards its realtime flags with\n"
        "// `sreg = SREG; cli(); flags |= mask; SREG = sreg;` (system.c), in the main program and in interrupts\n"
        "// ('?' in the serial RX interrupt, cycle stop in the stepper's). If an interrupt saved SREG while the\n"
        "// main program was between its cli() and its restore, the interrupt saved I=0 and wrote it back after the\n"
        "// main program had set I again: interrupts stayed disabled for ever, the stepper interrupt never ran again\n"
        "// (MPos frozen in Run, a feed hold stuck in Hold:1) while the serial port, which the sim runs whatever I\n"
        "// says, kept answering. On the AVR an interrupt cannot run inside the main program's cli() section, and\n"
        "// enters with I clear and leaves with RETI. So: the main program's thread (sim_enter_avr_main()) works on\n"
        "// io.sreg, which gates the interrupts (timer_interrupts, rig_hw.c); code run as an interrupt works on a\n"
        "// register of its own thread, which gates nothing (the sim never nests interrupts).\n"
        "static __thread uint8_t isr_sreg = 0;\n"
        "static __thread uint8_t avr_main_context = 0;\n"
        "void sim_enter_avr_main(void) { avr_main_context = 1; }\n"
        "volatile uint8_t *sim_sreg(void) { return avr_main_context ? &io.sreg : &isr_sreg; }\n"
        "void sei() {SREG|=SEI;}\nvoid cli() {SREG&=~SEI;}\n",
    ),
    Patch(
        "sreg-per-thread: main program", "grbl-sim/main.c",
        "PLAT_THREAD_FUNC(avr_main_thread,exit){\n  avr_main();\n",
        "void sim_enter_avr_main(void); // rig patch: this thread is the AVR's main program (avr/interrupt.c)\n"
        "PLAT_THREAD_FUNC(avr_main_thread,exit){\n  sim_enter_avr_main();\n  avr_main();\n",
    ),
    Patch(
        "sreg-per-thread: atomic flags (set)", "system.c",
        "  sys_rt_exec_state |= (mask);\n",
        "  // rig patch: on the host, cli() in one thread does not stop an interrupt already running in the other;\n"
        "  // make the read-modify-write of the flags atomic so that neither loses the other's bit\n"
        "  __atomic_or_fetch(&sys_rt_exec_state, (mask), __ATOMIC_SEQ_CST);\n",
    ),
    Patch(
        "sreg-per-thread: atomic flags (clear)", "system.c",
        "  sys_rt_exec_state &= ~(mask);\n",
        "  __atomic_and_fetch(&sys_rt_exec_state, (uint8_t)~(mask), __ATOMIC_SEQ_CST); // rig patch: atomic\n",
    ),
    Patch(
        "sreg-per-thread: atomic flags (motion override)", "system.c",
        "  sys_rt_exec_motion_override |= (mask);\n",
        "  __atomic_or_fetch(&sys_rt_exec_motion_override, (mask), __ATOMIC_SEQ_CST); // rig patch: atomic\n",
    ),
    Patch(
        "sreg-per-thread: atomic flags (accessory override)", "system.c",
        "  sys_rt_exec_accessory_override |= (mask);\n",
        "  __atomic_or_fetch(&sys_rt_exec_accessory_override, (mask), __ATOMIC_SEQ_CST); // rig patch: atomic\n",
    ),
    Patch(
        "segment-underrun: wait", "stepper.c",
        "ISR(TIMER1_COMPA_vect)\n{\n",
        "// rig patch: on the AVR the main program preps step segments while this interrupt runs them, always fast\n"
        "// enough that the segment buffer runs dry only where the motion ends. On a loaded host the main program's\n"
        "// thread can wait for a core for tens of ms while the simulator's thread catches up with real time at many\n"
        "// times its pace; the buffer then ran dry mid-move and GRBL ended the motion there: a cycle went Idle short\n"
        "// of its target (and started again), a homing search ended without its switch (ALARM:9). While the main\n"
        "// program owes a segment (a cycle, homing or jog whose motion is not ending: a system motion not fully\n"
        "// prepped, or a block still planned), wait for it here: the simulated time stands still, as the AVR's\n"
        "// would have gone on only with it (at most RIG_UNDERRUN_WAIT_US, so that nothing can hang on it). If the\n"
        "// main program stops the stepper meanwhile (st_go_idle: its interrupt disabled), this interrupt is\n"
        "// dropped, as the AVR would not have run it.\n"
        "#define RIG_UNDERRUN_WAIT_US 2000000L\n"
        "void platform_sleep(long microsec);\n"
        "static int rig_wait_for_segment(void) {  // 1: drop this interrupt\n"
        "  for (long waited = 0; waited < RIG_UNDERRUN_WAIT_US; waited += 50) {\n"
        "    if (!(*(volatile uint8_t *)&TIMSK1 & (1 << OCIE1A))) { return waited > 0; }\n"
        "    if (*(volatile uint8_t *)&segment_buffer_head != segment_buffer_tail) { return 0; }\n"
        "    if (!(*(volatile uint8_t *)&sys.state & (STATE_CYCLE | STATE_HOMING | STATE_JOG))) { return 0; }\n"
        "    uint8_t control = *(volatile uint8_t *)&sys.step_control;\n"
        "    if (control & STEP_CONTROL_END_MOTION) { return 0; }\n"
        "    if (!(control & STEP_CONTROL_EXECUTE_SYS_MOTION) && plan_get_current_block() == NULL) { return 0; }\n"
        "    platform_sleep(50);\n"
        "  }\n"
        "  return 0;\n"
        "}\n\n"
        "ISR(TIMER1_COMPA_vect)\n{\n",
    ),
    Patch(
        "segment-underrun: call", "stepper.c",
        "    // Anything in the buffer? If so, load and initialize next step segment.\n"
        "    if (segment_buffer_head != segment_buffer_tail) {\n",
        "    if (rig_wait_for_segment()) { busy = false; return; } // rig patch (above the interrupt)\n"
        "    // Anything in the buffer? If so, load and initialize next step segment.\n"
        "    if (*(volatile uint8_t *)&segment_buffer_head != segment_buffer_tail) {\n",
    ),
)

RIG_HW_C = r"""/*
  rig_hw.c - the machine around the controller, and a cheaper clock, for rig's tests. Written for rig (MIT) and
  added to the grbl-sim build by rig's tests/grbl_firmware.py; not part of grbl-sim.

  A one-axis linear stage. X drives a carriage on a rail GRBL_SIM_RAIL_MM long (default 200); at power-up the
  carriage is at GRBL_SIM_X0_MM (default: the middle), measured from the rail's -X end.
  - The stepper driver moves the carriage 1/$100 mm on each rising edge of the X step pin, towards -X while the
    X direction pin is high (the wiring GRBL's stock $2=0, $3=0 expect; with other $2/$3 the machine behaves
    as a real one wired that way would). At either end the carriage stops against the end: further steps are lost.
  - A normally-open switch at each end closes at or beyond that end; both are wired to the X limit pin, which
    they pull low; open, the pin reads high (GRBL's internal pull-up). So with $5=0 GRBL reads "triggered" at
    either end. The Y and Z limit pins, the probe pin and the reset, feed hold and cycle start inputs read open.
  - A change of the X limit pin raises the limit pin-change interrupt when GRBL has enabled it (PCICR/PCMSK,
    i.e. $21=1), at once or as soon as GRBL re-enables interrupts, as on the AVR.
  - The carriage position goes to CARRIAGE.TXT in the working folder ("<mm> <mm>\n", the number twice and fixed
    width, so a reader can spot a torn read) with one pwrite: at power-up, then at most every 1 ms of sim time
    while it changes, and as soon as the stepper stops. A killed process leaves where the carriage was.

  The clock: grbl-sim runs every 16 MHz tick of the AVR's timers, most of which change nothing but a counter.
  rig_hw_skip() jumps over the ticks before the next one in which an interrupt can fire (a timer reaching a compare
  value or overflowing, on a timer with a vector), the serial port has work (a byte to send at the baud tick, a
  poll of stdin due) or the carriage file is due; it advances the prescaler and those timers' counters by as much.
  Timers with no interrupt enabled (Timer1 while the stepper is idle, Timer2 for the spindle PWM) are left frozen.
  Between batches of ticks the simulator sleeps (rig_hw_sleep) in select() until a byte arrives on stdin, GRBL's
  main program queues a byte to send (rig_tx_kick, from serial_write), or 1 ms has passed, whether the stepper
  runs or not, then runs the ticks of the time slept at once (catching up with real time, as before). Nothing
  else outside the simulator's thread waits on its ticks: the main program sees the steps, the carriage file
  and the switches of up to 1 ms of sim time land together (an incoming byte ends the sleep, so a `?` is
  answered with the position at the time it came). When select() said stdin was empty, the ticks it slept over
  poll stdin no more (rig_hw_catch_up); when it said a byte is there, the byte is read at the last of them, the
  tick of its arrival.
*/

#define _GNU_SOURCE  // pipe2
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/select.h>
#include <unistd.h>

#include "simulator.h"
#include "avr/io.h"
#include "avr/interrupt.h"
#include "../grbl.h"

uint64_t rig_next_poll = 0;  // no poll of stdin before this tick (platform_LINUX.c)
volatile uint8_t rig_isr_active = 0;  // an interrupt raised here is running (protocol.c waits)
static int rig_sleeping = 0;  // the simulator's thread is (about to be) in select(): rig_tx_kick() wakes it
static int kick_fd[2] = {-1, -1};  // the pipe rig_tx_kick() writes to
enum { STDIN_UNKNOWN, STDIN_EMPTY, STDIN_READY };
static int stdin_seen = STDIN_UNKNOWN;  // what the last select() said of stdin
extern uint8_t serial_tx_buffer_head;
extern volatile uint8_t serial_tx_buffer_tail;
extern uint8_t serial_rx_buffer_head;
extern volatile uint8_t serial_rx_buffer_tail;
extern int16_t sim_scaling[8];
static const uint16_t bitmask[SIM_N_TIMERS] = {0xFF, 0xFFFF, 0xFF};

static double rail_mm = 200.0;
static double carriage_mm = 100.0;
static double written_mm = -1e300;
static uint64_t written_tick = 0;
static uint8_t step_level = 0;
static uint8_t limit_change_pending = 0;
static int carriage_fd = -1;

static double env_mm(const char *name, double fallback) {
  const char *text = getenv(name);
  char *end;
  if (!text || !*text) { return fallback; }
  double value = strtod(text, &end);
  if (*end) { fprintf(stderr, "rig_hw: %s=%s is not a number\n", name, text); exit(2); }
  return value;
}

static void set_limit_pins(void) {
  uint8_t before = LIMIT_PIN;
  uint8_t level = LIMIT_MASK;  // open switches read high
  if (carriage_mm <= 0.0 || carriage_mm >= rail_mm) { level &= ~(1 << X_LIMIT_BIT); }
  LIMIT_PIN = (before & ~LIMIT_MASK) | level;
  if (((before ^ LIMIT_PIN) & LIMIT_PCMSK) && (PCICR & (1 << LIMIT_INT))) { limit_change_pending = 1; }
}

static void write_carriage(void) {
  char text[64];
  int n = snprintf(text, sizeof text, "%20.6f %20.6f\n", carriage_mm, carriage_mm);
  if (carriage_fd >= 0 && pwrite(carriage_fd, text, n, 0) != n) { perror("rig_hw: CARRIAGE.TXT"); }
  written_mm = carriage_mm;
  written_tick = sim.masterclock;
}

void rig_hw_init(void) {
  rail_mm = env_mm("GRBL_SIM_RAIL_MM", 200.0);
  carriage_mm = env_mm("GRBL_SIM_X0_MM", rail_mm / 2);
  if (carriage_mm < 0.0) { carriage_mm = 0.0; }
  if (carriage_mm > rail_mm) { carriage_mm = rail_mm; }
  CONTROL_PIN |= CONTROL_MASK;  // reset, feed hold, cycle start: open
  PROBE_PIN |= PROBE_MASK;      // probe: open
  set_limit_pins();
  limit_change_pending = 0;
  carriage_fd = open("CARRIAGE.TXT", O_WRONLY | O_CREAT | O_TRUNC, 0644);
  write_carriage();
  if (pipe2(kick_fd, O_NONBLOCK | O_CLOEXEC) != 0) { perror("rig_hw: pipe"); exit(2); }
}

static int stepper_stopped(void) { return !(TIMSK1 & (1 << OCIE1A)) && !(TCCR0B & 7); }

void rig_hw_tick(void) {
  uint8_t level = STEP_PORT & (1 << X_STEP_BIT);
  if (level && !step_level) {
    double step_mm = 1.0 / settings.steps_per_mm[X_AXIS];
    carriage_mm += (DIRECTION_PORT & (1 << X_DIRECTION_BIT)) ? -step_mm : step_mm;
    if (carriage_mm < 0.0) { carriage_mm = 0.0; }
    if (carriage_mm > rail_mm) { carriage_mm = rail_mm; }
    set_limit_pins();
  }
  step_level = level;
  if (limit_change_pending && (io.sreg & SEI)) {  // the main program's I bit (SREG here is this thread's)
    limit_change_pending = 0;
    if ((PCICR & (1 << LIMIT_INT)) && pc_vect) {
      rig_isr_active = 1;  // GRBL's main program waits (protocol_exec_rt_system) until the interrupt is over
      pc_vect();
      rig_isr_active = 0;
    }
  }
  if (carriage_mm != written_mm && (sim.masterclock - written_tick >= F_CPU / 1000 || stepper_stopped())) {
    write_carriage();
  }
}

static int tx_empty(void) { return serial_tx_buffer_tail == *(volatile uint8_t *)&serial_tx_buffer_head; }

// can timer i call an interrupt vector? (the sim calls a timer's overflow vector whatever TIMSK says)
static int timer_has_vector(int i) {
  return ((io.timsk[i] & (1 << SIM_OCA)) && compa_vect[i]) || ((io.timsk[i] & (1 << SIM_OCB)) && compb_vect[i]) ||
         ovf_vect[i];
}

// no interrupt can fire, nothing is being sent, the carriage file is up to date: ticks change nothing
static int rig_hw_idle(void) {
  for (int i = 0; i < SIM_N_TIMERS; i++) {
    if (sim_scaling[io.tccrb[i] & 7] && timer_has_vector(i)) { return 0; }
  }
  return tx_empty() && !limit_change_pending && carriage_mm == written_mm;
}

// Advance the clock over the ticks before `until` in which nothing can happen; the caller then runs one tick.
void rig_hw_skip(uint64_t until, uint64_t *next_byte_tick) {
  uint64_t now = sim.masterclock;
  if (now + 1 >= until || limit_change_pending) { return; }
  if (rig_hw_idle()) {  // nothing can happen: jump to the present and poll the serial port there
    sim.masterclock = until - 1;
    io.prescaler += (uint16_t)(until - 1 - now);
    if (*next_byte_tick < sim.masterclock) { *next_byte_tick = sim.masterclock; }
    return;
  }
  uint64_t last = until - 1;  // the last tick we may skip
  if (carriage_mm != written_mm) {
    if (stepper_stopped()) { return; }
    uint64_t due = written_tick + F_CPU / 1000;
    if (due <= now + 1) { return; }
    if (due - 1 < last) { last = due - 1; }
  }
  // the serial port: a byte to send goes at the next baud tick; else the next poll of stdin is the next work
  if (tx_empty()) {
    uint8_t rx_next = serial_rx_buffer_head + 1;
    if (rx_next == RX_BUFFER_SIZE) { rx_next = 0; }
    uint64_t due = rx_next == serial_rx_buffer_tail ? now + F_CPU / 20000 : rig_next_poll;  // buffer full: recheck
    if (*next_byte_tick < due) { *next_byte_tick = due; }  // the baud ticks before it would do nothing
  }
  if (*next_byte_tick <= now + 1) { return; }
  if (*next_byte_tick - 1 < last) { last = *next_byte_tick - 1; }
  // the timers: stop before the tick of the next increment that reaches 0 or a compare value
  uint16_t prescaler = io.prescaler;
  for (int i = 0; i < SIM_N_TIMERS; i++) {
    uint16_t inc = sim_scaling[io.tccrb[i] & 7];
    if (!inc || !timer_has_vector(i)) { continue; }
    uint64_t first = inc - (prescaler & (inc - 1));  // ticks to its next increment
    uint8_t pending = (1 << SIM_ROLL) | (compa_vect[i] ? 1 << SIM_OCA : 0) | (compb_vect[i] ? 1 << SIM_OCB : 0) |
                      (ovf_vect[i] ? 1 << SIM_TOV : 0);
    uint32_t k = (uint32_t)bitmask[i] + 1;  // increments to the next interesting count
    if (io.tifr[i] & pending) {
      k = 1;
    } else {
      uint16_t count = io.tcnt[i] & bitmask[i];
      uint16_t targets[4] = {0, io.ocra[i], io.ocrb[i], io.ocrc[i]};
      for (int t = 0; t < 4; t++) {
        uint32_t d = (uint16_t)((targets[t] & bitmask[i]) - count) & bitmask[i];
        if (d == 0) { d = (uint32_t)bitmask[i] + 1; }
        if (d < k) { k = d; }
      }
    }
    uint64_t event = now + first + (uint64_t)(k - 1) * inc;  // the tick of that increment
    if (event <= now + 1) { return; }
    if (event - 1 < last) { last = event - 1; }
  }
  uint64_t skip = last - now;
  for (int i = 0; i < SIM_N_TIMERS; i++) {
    uint16_t inc = sim_scaling[io.tccrb[i] & 7];
    if (!inc || !timer_has_vector(i)) { continue; }
    uint64_t increments = ((prescaler & (inc - 1)) + skip) / inc;
    io.tcnt[i] = (io.tcnt[i] + increments) & bitmask[i];
  }
  io.prescaler = prescaler + (uint16_t)skip;
  sim.masterclock = last;
}

static int rx_full(void) {
  uint8_t next = serial_rx_buffer_head + 1;
  if (next == RX_BUFFER_SIZE) { next = 0; }
  return next == serial_rx_buffer_tail;
}

// GRBL's main program queued a byte to send (serial_write): wake the simulator's thread if it sleeps. With the
// fences, either that thread sees the byte before it sleeps or this one sees it sleeping (and writes the pipe).
void rig_tx_kick(void) {
  __atomic_thread_fence(__ATOMIC_SEQ_CST);
  if (__atomic_load_n(&rig_sleeping, __ATOMIC_RELAXED) && __atomic_exchange_n(&rig_sleeping, 0, __ATOMIC_SEQ_CST)) {
    char byte = 1;
    if (write(kick_fd[1], &byte, 1) < 0) { /* the pipe is full: a wake-up is pending anyway */ }
  }
}

// The ticks up to `until` are about to run: no poll of stdin in them when select() found it empty since (a byte
// that comes meanwhile ends the next sleep at once); a byte it found is read at the last of them, when it came.
void rig_hw_catch_up(uint64_t until) {
  if (stdin_seen == STDIN_EMPTY) {
    if (rig_next_poll < until) { rig_next_poll = until; }
  } else if (stdin_seen == STDIN_READY) {
    rig_next_poll = until > sim.masterclock + 1 ? until - 1 : sim.masterclock;
  }
  stdin_seen = STDIN_UNKNOWN;
}

#define RIG_SLEEP_MAX_US 1000
// Sleep until a byte comes on stdin, GRBL queues one to send, or RIG_SLEEP_MAX_US have passed. The simulator
// has caught up with real time; whatever the ticks of the sleep hold (steps, the carriage file) runs after it.
void rig_hw_sleep(uint64_t next_byte_tick) {
  static int eof = 0;
  if (limit_change_pending) { platform_sleep(0); return; }  // the limit interrupt waits for GRBL's sei(): soon
  long sleep_us = RIG_SLEEP_MAX_US;
  __atomic_store_n(&rig_sleeping, 1, __ATOMIC_SEQ_CST);
  __atomic_thread_fence(__ATOMIC_SEQ_CST);
  if (!tx_empty()) {  // a byte to send: sleep until its baud tick (no output in the first second of sim time)
    __atomic_store_n(&rig_sleeping, 0, __ATOMIC_SEQ_CST);
    uint64_t wait = next_byte_tick > sim.masterclock ? next_byte_tick - sim.masterclock : 0;
    if (wait < F_CPU / 20000) { return; }  // due within 50 us: run the ticks to it now
    if (wait < (uint64_t)RIG_SLEEP_MAX_US * (F_CPU / 1000000)) { sleep_us = wait / (F_CPU / 1000000); }
  }
  if (!eof && feof(stdin)) { eof = 1; }  // nothing more will come: stdin would always be readable
  // watch stdin only when a byte there would be read soon (not in the first second, not with GRBL's RX ring full)
  int watch = !eof && !rx_full() && next_byte_tick <= sim.masterclock + F_CPU / 1000;
  fd_set readable;
  struct timeval timeout = {0, sleep_us};
  FD_ZERO(&readable);
  FD_SET(kick_fd[0], &readable);
  if (watch) { FD_SET(STDIN_FILENO, &readable); }
  int n = select((kick_fd[0] > STDIN_FILENO ? kick_fd[0] : STDIN_FILENO) + 1, &readable, NULL, NULL, &timeout);
  __atomic_store_n(&rig_sleeping, 0, __ATOMIC_SEQ_CST);
  if (n < 0) { FD_ZERO(&readable); }  // EINTR
  if (FD_ISSET(kick_fd[0], &readable)) {
    char drain[64];
    while (read(kick_fd[0], drain, sizeof drain) > 0) {}
  }
  if (watch) { stdin_seen = FD_ISSET(STDIN_FILENO, &readable) ? STDIN_READY : STDIN_EMPTY; }
  if (n < 0) { stdin_seen = STDIN_UNKNOWN; }
}
"""

NEW_FILES: dict[str, str] = {"grbl-sim/rig_hw.c": RIG_HW_C}


def apply_patches(grbl_dir: Path, patches: Iterable[Patch] = PATCHES, new_files: dict[str, str] = NEW_FILES) -> None:
    """Apply each patch to the unpacked grbl/ folder: its anchor must occur exactly once."""
    for patch in patches:
        path = grbl_dir / patch.path
        text = path.read_text(encoding="latin-1")
        count = text.count(patch.anchor)
        if count != 1:
            raise RuntimeError(f"grbl patch {patch.name!r}: anchor found {count} times in {patch.path} (expected once)"
                               f"; the vendored source changed? anchor: {patch.anchor!r}")
        path.write_text(text.replace(patch.anchor, patch.replacement), encoding="latin-1")
    for rel, text in new_files.items():
        (grbl_dir / rel).write_text(text, encoding="latin-1")


# ---------------------------------------------------------------------------------------------------------------
# Building
# ---------------------------------------------------------------------------------------------------------------


def missing_toolchain() -> str | None:
    """Why the firmware cannot be built here (one line), or None."""
    if not TARBALL.is_file():
        return f"the GRBL firmware source is missing ({TARBALL.relative_to(HERE.parent)})"
    if not (shutil.which("cc") or shutil.which("gcc")):
        return "no C compiler (cc or gcc) to build the GRBL 1.1h firmware for the host"
    if not shutil.which("make"):
        return "no make to build the GRBL 1.1h firmware for the host"
    return None


def build_key(patches: Iterable[Patch] = PATCHES) -> str:
    """A hash of the tarball, the patches, the new files and the build flags."""
    digest = hashlib.sha256(TARBALL.read_bytes())
    digest.update(repr((tuple(patches), sorted(NEW_FILES.items()), MAKE_FLAGS)).encode())
    return digest.hexdigest()[:16]


def patches_without(*prefixes: str) -> tuple[Patch, ...]:
    """PATCHES minus those whose name starts with one of `prefixes` (for experiments: build_firmware(patches=...)
    builds such a variant into its own folder). Every prefix must match a patch."""
    for prefix in prefixes:
        if not any(p.name.startswith(prefix) for p in PATCHES):
            raise ValueError(f"no patch named {prefix!r}...; the patches: {[p.name for p in PATCHES]}")
    return tuple(p for p in PATCHES if not p.name.startswith(prefixes))


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rig-tests"


def build_firmware(patches: Iterable[Patch] | None = None) -> Path:
    """Build grbl_sim.exe (once per tarball-and-patches hash) and return its path. Safe across processes.
    `patches` (default PATCHES; see patches_without()) builds a variant, into its own folder."""
    patches = PATCHES if patches is None else tuple(patches)
    root = cache_root()
    root.mkdir(parents=True, exist_ok=True)
    key = build_key(patches)
    final = root / f"grbl-{key}"
    exe = final / "grbl" / "grbl-sim" / EXE_NAME
    if exe.is_file():
        return exe
    with open(root / f"grbl-{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another worker may be building it: wait for it
        if exe.is_file():
            return exe
        work = Path(tempfile.mkdtemp(prefix=f"grbl-{key}.", dir=root))
        try:
            with tarfile.open(TARBALL) as tar:
                if hasattr(tarfile, "data_filter"):  # Python >= 3.11.4
                    tar.extractall(work, filter="data")
                else:
                    tar.extractall(work)
            apply_patches(work / "grbl", patches)
            env = dict(os.environ)
            if not shutil.which("cc"):
                env["CC"] = "gcc"
            make = subprocess.run(["make", f"-j{min(4, os.cpu_count() or 1)}", "main", f"FLAGS={MAKE_FLAGS}"],
                                  cwd=work / "grbl" / "grbl-sim", env=env, capture_output=True, text=True)
            if make.returncode != 0 or not (work / "grbl" / "grbl-sim" / EXE_NAME).is_file():
                raise RuntimeError(f"building the GRBL firmware failed (make exit {make.returncode}):\n"
                                   f"{(make.stdout + make.stderr)[-4000:]}")
            (work / "BUILD.txt").write_text(f"make main FLAGS={MAKE_FLAGS!r}\npatches: "
                                            + ", ".join(p.name for p in patches) + "\n")
            if final.exists():  # a half-removed leftover of an interrupted run
                shutil.rmtree(final)
            os.rename(work, final)
        finally:
            if work.exists():
                shutil.rmtree(work, ignore_errors=True)
    return exe


def require_firmware() -> Path:
    """The built firmware, or skip the calling test with a one-line reason (no compiler / make)."""
    import pytest

    reason = missing_toolchain()
    if reason:
        pytest.skip(reason)
    return build_firmware()


# ---------------------------------------------------------------------------------------------------------------
# Running it
# ---------------------------------------------------------------------------------------------------------------


class Traffic(NamedTuple):
    t: float  # seconds since the harness started (time.monotonic based)
    data: bytes | str


GARBLE_KINDS = ("letter", "separator", "non_ascii", "truncate")
_SIM_CLOCK_LINE = re.compile(rb"^\d+ \d+\.\d+\n$")  # grbl-sim's answer to '%'


def garble_status(line: bytes, kind: str) -> bytes:
    """A status report `<...>\\r\\n` as a noisy USB-serial link might deliver it."""
    body = line.rstrip(b"\r\n")
    match = re.search(rb"\|([A-Za-z]+):", body)
    if kind == "letter":  # one letter of the first field name replaced by its neighbour: MPos -> MPPs
        if not match or len(match.group(1)) < 3:
            raise ValueError(f"no field name to garble in {line!r}")
        i = match.start(1) + 2
        return body[:i] + body[i - 1:i] + body[i + 1:] + b"\r\n"
    if kind == "separator":  # the first field's ':' doubled: MPos::5.964
        if not match:
            raise ValueError(f"no field to garble in {line!r}")
        return body[:match.end()] + b":" + body[match.end():] + b"\r\n"
    if kind == "non_ascii":  # bit 7 set on the first digit (or the middle byte): '5' -> 0xB5
        digit = re.search(rb"\d", body)
        i = digit.start() if digit else len(body) // 2
        return body[:i] + bytes([body[i] | 0x80]) + body[i + 1:] + b"\r\n"
    if kind == "truncate":  # cut in the middle: no line end, the rest of the line lost
        return body[:max(1, len(body) // 2)]
    raise ValueError(f"unknown garble kind {kind!r} (one of {GARBLE_KINDS})")


class _Faults:
    """What the bridge should do to the traffic; shared by the sessions of one GrblFirmware."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.garble: deque[str] = deque()  # kinds for the next status reports
        self.garble_forever: str | None = None
        self.delays: deque[tuple[float, bytes | None]] = deque()  # (seconds, line prefix or None)
        self.drops: dict[int, int] = {}  # byte -> how many more to drop (-1: all)
        self.stall_until = 0.0

    def clear(self) -> None:
        with self.lock:
            self.garble.clear()
            self.garble_forever = None
            self.delays.clear()
            self.drops.clear()
            self.stall_until = 0.0


class _Log:
    def __init__(self) -> None:
        self.t0 = time.monotonic()
        self.sent: list[Traffic] = []
        self.lines: list[Traffic] = []
        self.changed = threading.Condition()

    def now(self) -> float:
        return time.monotonic() - self.t0


class _Session:
    """One firmware process, its pseudo-terminal and the bridge thread between them."""

    def __init__(self, exe: Path, workdir: Path, env: dict[str, str], faults: _Faults, log: _Log,
                 used_ports: Iterable[str] = ()) -> None:
        self.faults, self.log = faults, log
        self.proc: subprocess.Popen | None = None
        self.master = self.slave = -1
        self.port = ""
        self.forwarding = False  # lines go to the client (else only to the harness)
        self.capture: deque[str] | None = None  # lines for the harness while set
        self.exited = threading.Event()
        self.closed = False
        self.bridge_error: BaseException | None = None
        self._to_fw = bytearray()
        self._harness_to_fw = bytearray()
        self._held_from_client: list[bytes] = []
        self._to_client: deque[tuple[float, bytes]] = deque()  # (release time, bytes), in order
        self._partial = b""
        self._partial_since = 0.0
        self._lock = threading.Lock()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self.master, self.slave = self._openpty(set(used_ports))
        tty.setraw(self.slave)  # we keep the slave open too: no EIO on the master while no client has it open
        os.set_blocking(self.master, False)
        self.port = os.ttyname(self.slave)
        self.stderr = open(workdir / "grbl_sim.stderr", "ab")
        try:
            self.proc = subprocess.Popen([str(exe), "-n", "-s", "/dev/null", "-b", "/dev/null"], cwd=workdir,
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr,
                                         env=env, start_new_session=True)
        except BaseException:
            for fd in (self.master, self.slave, self._wake_r, self._wake_w):
                os.close(fd)
            self.stderr.close()
            raise
        self.fw_in, self.fw_out = self.proc.stdin.fileno(), self.proc.stdout.fileno()
        os.set_blocking(self.fw_in, False)
        self.thread = threading.Thread(target=self._bridge, name=f"grbl-bridge-{self.proc.pid}", daemon=True)
        self.thread.start()

    @staticmethod
    def _openpty(used: set[str]) -> tuple[int, int]:
        """A pty pair whose slave path is not in `used` (the kernel hands out the lowest free number, so a
        re-plugged controller would get its old path back: hold those while asking again)."""
        held: list[int] = []
        try:
            for _ in range(64):
                master, slave = os.openpty()
                if os.ttyname(slave) not in used:
                    return master, slave
                held += [master, slave]
            raise FirmwareError(f"no new pseudo-terminal (all of {sorted(used)} came back)")
        finally:
            for fd in held:
                os.close(fd)

    # -- the bridge thread ----------------------------------------------------------------------------------

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except (BlockingIOError, OSError):
            pass

    def send_from_harness(self, data: bytes) -> None:
        with self._lock:
            self._harness_to_fw += data
        self._wake()

    def _from_client(self, data: bytes, now: float) -> None:
        self.log.sent.append(Traffic(self.log.now(), data))
        with self.faults.lock:
            for byte, left in list(self.faults.drops.items()):
                i = data.find(bytes([byte]))
                while i >= 0 and left != 0:
                    data = data[:i] + data[i + 1:]
                    left -= 1
                    i = data.find(bytes([byte]))
                if left == 0:
                    del self.faults.drops[byte]
                else:
                    self.faults.drops[byte] = left
            stalled = now < self.faults.stall_until
        data = data.replace(b"\x06", b"").replace(b"\xff", b"")  # a real GRBL ignores these; grbl-sim exits
        if stalled:
            self._held_from_client.append(data)
        else:
            self._to_fw += data

    def _from_firmware(self, data: bytes, now: float) -> None:
        data = self._partial + data
        *lines, self._partial = data.split(b"\n")
        for line in lines:
            self._line(line + b"\n", now)
        if self._partial:
            self._partial_since = now

    def _line(self, raw: bytes, now: float) -> None:
        text = raw.rstrip(b"\r\n").decode("latin-1")
        with self.log.changed:
            self.log.lines.append(Traffic(self.log.now(), text))
            self.log.changed.notify_all()
        if self.capture is not None:
            self.capture.append(text)
            return
        if not self.forwarding or _SIM_CLOCK_LINE.match(raw):
            return
        release = now
        with self.faults.lock:
            if raw.startswith(b"<"):
                kind = self.faults.garble.popleft() if self.faults.garble else self.faults.garble_forever
                if kind:
                    try:
                        raw = garble_status(raw, kind)
                    except ValueError:  # nothing of that kind to garble: pass it on as it is
                        pass
            if self.faults.delays:
                seconds, prefix = self.faults.delays[0]
                if prefix is None or raw.startswith(prefix):
                    self.faults.delays.popleft()
                    release = now + seconds
            release = max(release, self.faults.stall_until)
        if self._to_client:
            release = max(release, self._to_client[-1][0])  # keep the order
        self._to_client.append((release, raw))

    def _bridge(self) -> None:
        try:
            self._bridge_loop()
        except BaseException as exc:  # keep it for the tests to see; the link goes silent, as a broken one would
            self.bridge_error = exc
            raise

    def _bridge_loop(self) -> None:
        out_buf = b""
        fw_open = client_open = True
        while not self.closed:
            now = time.monotonic()
            with self.faults.lock:
                stall_until = self.faults.stall_until
            if self._held_from_client and now >= stall_until:
                self._to_fw += b"".join(self._held_from_client)
                self._held_from_client.clear()
            if self._partial and now - self._partial_since > 0.05:  # a line that does not end: pass it on
                raw, self._partial = self._partial, b""
                self._line(raw, now)
            while self._to_client and self._to_client[0][0] <= now:
                out_buf += self._to_client.popleft()[1]
            with self._lock:
                if self._harness_to_fw:
                    self._to_fw += self._harness_to_fw
                    self._harness_to_fw.clear()
            timeout = 0.05
            if self._to_client:
                timeout = min(timeout, max(0.0, self._to_client[0][0] - now))
            if self._held_from_client:
                timeout = min(timeout, max(0.0, stall_until - now))
            rlist = [self._wake_r] + ([self.fw_out] if fw_open else []) + ([self.master] if client_open else [])
            wlist = ([self.master] if out_buf and client_open else [])
            wlist += [self.fw_in] if self._to_fw and fw_open else []
            try:
                readable, writable, _ = select.select(rlist, wlist, [], timeout)
            except (OSError, ValueError):
                return  # fds closed under us: the session is closing
            now = time.monotonic()
            if self._wake_r in readable:
                try:
                    os.read(self._wake_r, 4096)
                except BlockingIOError:
                    pass
            if self.fw_out in readable:
                try:
                    data = os.read(self.fw_out, 65536)
                except OSError:
                    data = b""
                if data:
                    self._from_firmware(data, now)
                else:
                    fw_open = False
                    self.exited.set()
            if self.master in readable:
                try:
                    data = os.read(self.master, 65536)
                except BlockingIOError:
                    data = None
                except OSError:  # EIO: no slave open (cannot happen while we hold one), or closed
                    data = b""
                if data:
                    self._from_client(data, now)
                elif data == b"":
                    client_open = False
            if self.master in writable and out_buf:
                try:
                    n = os.write(self.master, out_buf)
                    out_buf = out_buf[n:]
                except BlockingIOError:
                    pass
                except OSError:
                    out_buf, client_open = b"", False
            if self.fw_in in writable and self._to_fw:
                try:
                    n = os.write(self.fw_in, self._to_fw)
                    del self._to_fw[:n]
                except BlockingIOError:
                    pass
                except OSError:  # the firmware is gone
                    self._to_fw.clear()
                    fw_open = False

    # -- ending ----------------------------------------------------------------------------------------------

    def stop(self, *, graceful: bool) -> None:
        """End the process (Ctrl-F and EOF first when graceful, else SIGKILL) and close the pty and pipes."""
        if self.closed:
            return
        proc = self.proc
        if proc is not None and proc.poll() is None:
            if graceful:
                try:
                    os.set_blocking(self.fw_in, True)
                    os.write(self.fw_in, b"\x06")
                except OSError:
                    pass
                try:
                    proc.stdin.close()
                except OSError:
                    pass
                try:
                    proc.wait(0.5)
                except subprocess.TimeoutExpired:
                    pass
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            proc.wait()
        self.closed = True
        self._wake()
        if self.thread is not threading.current_thread():
            self.thread.join(5)
        for fd in (self.master, self.slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        for stream in (proc.stdin, proc.stdout) if proc else ():
            try:
                stream.close()
            except OSError:
                pass
        self.stderr.close()


def _stop_all(sessions: list[_Session]) -> None:
    for session in sessions:
        session.stop(graceful=False)


def _format_value(value: float) -> str:
    value = float(value)
    return str(int(value)) if value.is_integer() else repr(value)


class FirmwareError(RuntimeError):
    pass


class GrblFirmware:
    """The real GRBL 1.1h (grbl-sim) on a pseudo-terminal, with faults on the link. A context manager.

    `settings` ({110: 3000, ...}) and `startup_lines` (for $N0, $N1) are written once the start-up burst is over
    ($22 before $20: soft limits need homing on), each waited for its `ok`; then, if there were any, the
    controller is power-cycled (a new process on the same EEPROM.DAT and carriage position) so that the client
    meets it as it powers up with them ($22=1: Alarm, `[MSG:'$H'|'$X' to unlock]`). `reboot=False` skips that.
    """

    def __init__(self, workdir: Path, *, rail_mm: float = 200.0, x0_mm: float | None = None,
                 settings: dict[int, float] | None = None, startup_lines: Iterable[str] = (),
                 reboot: bool | None = None, exe: Path | None = None, start_timeout_s: float = 15.0) -> None:
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.exe = Path(exe) if exe else build_firmware()
        self.rail_mm = float(rail_mm)
        self.x0_mm = self.rail_mm / 2 if x0_mm is None else float(x0_mm)
        self.start_timeout_s = start_timeout_s
        self.faults = _Faults()
        self._log = _Log()
        self._sessions: list[_Session] = []
        self._session: _Session | None = None
        self.startup_burst: list[str] = []
        self.starts = 0
        self._finalizer = weakref.finalize(self, _stop_all, self._sessions)
        try:
            self._start(self.x0_mm)
            settings = dict(settings or {})
            ordered = sorted(settings, key=lambda n: (n != 22, n != 20))  # $22 first, $20 next, then as given
            for n in ordered:
                self._expect_ok(f"${n}={_format_value(settings[n])}")
            startup_lines = list(startup_lines)
            if startup_lines and any("'$H'|'$X' to unlock" in line for line in self.startup_burst):
                self._expect_ok("$X")  # $N0=... is refused in Alarm (error:8)
            for i, line in enumerate(startup_lines):
                self._expect_ok(f"$N{i}={line}")
            if reboot if reboot is not None else bool(settings or startup_lines):
                self._session.stop(graceful=True)
                self._start(self.physical_x_mm())
            self._session.forwarding = True
        except BaseException:
            self.close()
            raise

    # -- life cycle ------------------------------------------------------------------------------------------

    def _env(self, x0_mm: float) -> dict[str, str]:
        return {**os.environ, "GRBL_SIM_RAIL_MM": repr(self.rail_mm), "GRBL_SIM_X0_MM": repr(float(x0_mm))}

    def _start(self, x0_mm: float) -> None:
        session = _Session(self.exe, self.workdir, self._env(x0_mm), self.faults, self._log,
                           used_ports=[s.port for s in self._sessions])
        session.capture = deque()
        self._sessions.append(session)
        self._session = session
        self.starts += 1
        deadline = time.monotonic() + self.start_timeout_s
        burst = self._collect(lambda lines: any(BANNER in line for line in lines), deadline, "the banner")
        # what follows the banner at once ([MSG:'$H'|'$X' to unlock]) belongs to the burst
        burst += self._collect(lambda lines: False, time.monotonic() + 0.1, None)
        self.startup_burst = burst
        session.capture = None

    def _collect(self, done: Callable[[list[str]], bool], deadline: float, what: str | None) -> list[str]:
        session = self._session
        got: list[str] = []
        with self._log.changed:
            while True:
                while session.capture:
                    got.append(session.capture.popleft())
                if done(got):
                    return got
                left = deadline - time.monotonic()
                if left <= 0 or session.exited.is_set() and not session.capture:
                    if what is None:
                        return got
                    state = "exited" if session.exited.is_set() else "running"
                    raise FirmwareError(f"no {what} from the GRBL firmware ({state}); it said: {got[-10:]}")
                self._log.changed.wait(min(left, 0.05))

    def query(self, text: str, timeout_s: float = 5.0) -> list[str]:
        """Send `text` + newline to the firmware from the harness (not through the client's pty) and return the
        lines it answers up to and including `ok` or `error:N`. Lines that arrive meanwhile go to the harness,
        not the client: use it while the client is quiet."""
        session = self._require_session()
        session.capture = deque()
        try:
            session.send_from_harness(text.encode("latin-1") + b"\n")
            return self._collect(lambda lines: bool(lines) and (lines[-1] == "ok" or lines[-1].startswith("error:")),
                                 time.monotonic() + timeout_s, f"reply to {text!r}")
        finally:
            session.capture = None

    def _expect_ok(self, line: str) -> None:
        reply = self.query(line)
        if reply[-1] != "ok":
            raise FirmwareError(f"{line!r}: {reply}")

    def status(self) -> str:
        """A status report, asked for by the harness (`?` and an empty line, which GRBL answers with ok)."""
        return next(line for line in self.query("?") if line.startswith("<"))

    def sim_clock(self) -> tuple[int, float]:
        """(ticks, seconds) of grbl-sim's clock (it answers '%'; GRBL then rejects the line "%")."""
        lines = self.query("%")
        match = next(re.match(r"^(\d+) (\d+\.\d+)$", line) for line in lines if re.match(r"^\d+ \d", line))
        return int(match.group(1)), float(match.group(2))

    def press(self, data: bytes) -> None:
        """Real-time bytes from the harness, as the controller's own buttons send them (`!` feed hold, `~` cycle
        start, Ctrl-X reset): the client does not see them sent."""
        self._require_session().send_from_harness(data)

    def kill(self) -> None:
        """SIGKILL the firmware and close the pty: the port goes away, like an unplugged controller."""
        session = self._require_session()
        session.stop(graceful=False)

    def restart(self) -> None:
        """Power the controller up again in the same folder (EEPROM kept; the carriage where it was, MPos 0) on a
        new pty, as a USB device re-enumerates: `.port` changes. Kills the running firmware first, if any."""
        if self._session is not None and not self._session.closed:
            self._session.stop(graceful=False)
        self._start(self.physical_x_mm())
        self._session.forwarding = True

    def close(self) -> None:
        for session in self._sessions:
            session.stop(graceful=True)
        self._finalizer.detach()

    def __enter__(self) -> GrblFirmware:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _require_session(self) -> _Session:
        if self._session is None or self._session.closed:
            raise FirmwareError("the firmware is not running (killed or closed): restart() it")
        return self._session

    # -- what the tests look at ------------------------------------------------------------------------------

    @property
    def port(self) -> str:
        """The pty slave's path (/dev/pts/N) to open with pyserial; a new one after restart() (after kill(), the
        path that went away)."""
        if self._session is None:
            raise FirmwareError("the firmware never started")
        return self._session.port

    @property
    def pid(self) -> int:
        return self._require_session().proc.pid

    @property
    def alive(self) -> bool:
        return self._session is not None and not self._session.closed and self._session.proc.poll() is None

    @property
    def sent(self) -> list[Traffic]:
        """Bytes from the client, as the bridge received them (before drops and stalls), with times."""
        return self._log.sent

    @property
    def lines(self) -> list[Traffic]:
        """Lines from the firmware (before any garbling), without line ends, with times."""
        return self._log.lines

    def sent_bytes(self) -> bytes:
        return b"".join(entry.data for entry in self._log.sent)

    def wait_for_line(self, test: Callable[[str], bool] | str, timeout_s: float = 5.0, *, after: float = 0.0) -> str:
        """The first firmware line at or after time `after` (harness seconds) that passes `test` (a regex)."""
        check = (lambda line: re.search(test, line) is not None) if isinstance(test, str) else test
        deadline = time.monotonic() + timeout_s
        with self._log.changed:
            while True:
                for entry in self._log.lines:
                    if entry.t >= after and check(entry.data):
                        return entry.data
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no line matching {test!r}; last lines: {[e.data for e in self.lines[-8:]]}")
                self._log.changed.wait(left)

    def now(self) -> float:
        """The harness clock of `.sent` and `.lines`."""
        return self._log.now()

    def physical_x_mm(self) -> float:
        """Where the carriage is on the rail (mm from its -X end), from CARRIAGE.TXT."""
        path = self.workdir / CARRIAGE_FILE
        for _ in range(100):
            fields = path.read_text().split()
            if len(fields) == 2 and fields[0] == fields[1]:
                return float(fields[0])
            time.sleep(0.001)  # a torn read: the firmware was writing it
        raise FirmwareError(f"{path} does not hold a position: {path.read_text()!r}")

    # -- faults (one-shot unless said otherwise) -------------------------------------------------------------

    def garble_next_status(self, kind: str = "letter") -> None:
        """Corrupt the next status report `<...>`: "letter" (MPos -> MPPs), "separator" (MPos::5.964),
        "non_ascii" (bit 7 set on a digit), "truncate" (half the line, no line end; the rest is lost)."""
        self.garble_status_reports(1, kind)

    def garble_status_reports(self, count: int | None = None, kind: str = "letter") -> None:
        """Corrupt the next `count` status reports, or every one until clear_faults() when count is None."""
        if kind not in GARBLE_KINDS:
            raise ValueError(f"unknown garble kind {kind!r} (one of {GARBLE_KINDS})")
        with self.faults.lock:
            if count is None:
                self.faults.garble_forever = kind
            else:
                self.faults.garble.extend([kind] * count)

    def delay_next_reply(self, seconds: float, prefix: bytes | None = None) -> None:
        """Hold the next line from the firmware (the next one starting with `prefix`, if given) for `seconds`;
        lines after it wait behind it."""
        with self.faults.lock:
            self.faults.delays.append((float(seconds), prefix))

    def drop_next(self, byte: bytes | int, count: int | None = 1) -> None:
        """Do not forward the next `count` occurrences of a byte from the client (None: all, until cleared)."""
        value = byte if isinstance(byte, int) else byte[0]
        with self.faults.lock:
            self.faults.drops[value] = -1 if count is None else self.faults.drops.get(value, 0) + count

    def stall(self, seconds: float) -> None:
        """Forward nothing in either direction for `seconds` (a stalled USB link), then deliver what was held."""
        with self.faults.lock:
            self.faults.stall_until = max(self.faults.stall_until, time.monotonic() + seconds)
        if self._session is not None:
            self._session._wake()

    def clear_faults(self) -> None:
        self.faults.clear()

