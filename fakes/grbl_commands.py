"""The `$` commands and the status report of the simulated GRBL 1.1h controller (`fakes/grbl_sim.py`),
as the firmware answers them (gnea/grbl wiki: commands.md, interface.md; grbl/report.c, system.c).
"""

from __future__ import annotations

import re
from typing import Any

from .grbl_settings import offsets_lines, parser_state, rate_text, settings_lines, write_setting

RX_BUFFER = 128
PLANNER_BLOCKS = 15


class GrblSystemCommands:
    """`$$`, `$N=value`, `$X`, `$H`, `$N`, `$Nx=line`, `$G`, `$#`, `$C`, `$I`, `$SLP`, `$`, `$J=`, and `?`'s report."""

    # provided by GrblSim
    settings: dict[int, float]
    state: str
    carriage: Any
    wco_counter: int
    ovr_counter: int

    def _system_command(self, line: str, now_s: float) -> None:
        if line.startswith("$J="):
            error = self._gcode(line[3:], now_s, jog=True)
            if error is not None:
                self.send_line(error)
            return
        setting = re.fullmatch(r"\$(\d+)=(.*)", line)
        startup = re.fullmatch(r"\$N([01])=(.*)", line)
        if line == "$X":
            if self.state == "Alarm":
                self.state = "Idle"
                self.send_line("[MSG:Caution: Unlocked]")
            self.send_line("ok")
        elif line == "$H":
            self._home(now_s)
        elif line == "$$":
            for text in settings_lines(self.settings):
                self.send_line(text)
            self.send_line("ok")
        elif setting:
            if self.state not in ("Idle", "Alarm"):
                self.send_line("error:8")
                return
            error = write_setting(self.settings, int(setting.group(1)), setting.group(2))
            self.carriage.speed_mm_s = self.settings[110] / 60.0
            self.carriage.accel_mm_s2 = self.settings[120]
            self.send_line(error or "ok")
        elif line == "$N":
            for i, text in enumerate(self.startup_lines):
                self.send_line(f"$N{i}={text}")
            self.send_line("ok")
        elif startup:
            self.startup_lines[int(startup.group(1))] = startup.group(2)
            self.send_line("ok")
        elif line == "$G":
            self.send_line(parser_state(motion=self.motion, inches=self.mm_per_unit != 1.0,
                                        relative=not self.absolute, feed_mm_min=self.feed_mm_min,
                                        report_inches=int(self.settings[13]) == 1))
            self.send_line("ok")
        elif line == "$#":
            for text in offsets_lines():
                self.send_line(text)
            self.send_line("ok")
        elif line == "$C":
            if self.state == "Check":
                self.send_line("[MSG:Disabled]")
                self.send_line("ok")
                self._soft_reset(now_s)
            elif self.state == "Idle":
                self.state = "Check"
                self.send_line("[MSG:Enabled]")
                self.send_line("ok")
            else:
                self.send_line("error:8")
        elif line == "$I":
            self.send_line("[VER:1.1h.20190830:]")
            self.send_line(f"[OPT:V{'Z' if self.force_origin else ''},15,128]")
            self.send_line("ok")
        elif line == "$SLP":
            if self.state not in ("Idle", "Alarm"):
                self.send_line("error:8")
                return
            self.send_line("ok")
            self.send_line("[MSG:Sleeping]")
            self.carriage.stop(now_s)
            self.state = "Sleep"
        elif line == "$":
            self.send_line("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
            self.send_line("ok")
        else:
            self.send_line("error:3")

    def _home(self, now_s: float) -> None:
        if not self.settings[22]:
            self.send_line("error:5")
        elif self.state not in ("Idle", "Alarm"):
            self.send_line("error:8")
        else:
            self.state = "Home"
            switch = self.travel_mm if self.homes_positive else 0.0
            fail = self.take_fault("homing_fail")
            stop_at = (self.carriage.position_mm(now_s) + switch) / 2 if fail else None
            self.carriage.start(switch, now_s, stop_at_mm=stop_at, stop_outcome="homing_fail",
                                speed_mm_s=self.settings[25] / 60.0)

    def _status(self, now_s: float) -> str:
        self.reports += 1
        inches = int(self.settings[13]) == 1
        scale, digits = (1 / 25.4, 4) if inches else (1.0, 3)
        x = self.machine_mm(now_s) * scale
        pos = f"{x:.{digits}f},{0:.{digits}f},{0:.{digits}f}"
        fields = [self.state, f"MPos:{pos}" if int(self.settings[10]) & 1 else f"WPos:{pos}"]
        if int(self.settings[10]) & 2:
            fields.append(f"Bf:{PLANNER_BLOCKS - len(self._queue)},{RX_BUFFER - len(self._rx)}")
        feed = self._target[1] if self._target and self.state in ("Run", "Jog") else 0.0
        fields.append(f"FS:{rate_text(min(feed, self.settings[110]), inches)},0")
        switch = self.travel_mm if self.homes_positive else 0.0
        if abs(self.carriage.position_mm(now_s) - switch) < 1e-6 or not 0 < self.carriage.position_mm(now_s) < self.travel_mm:
            fields.append("Pn:X")
        busy = self.state.split(":")[0] in ("Home", "Run", "Hold", "Jog", "Door")
        if self.wco_counter > 0:  # report.c: WCO, then Ov in the report after it, each on its own counter
            self.wco_counter -= 1
        else:
            self.wco_counter = (30 if busy else 10) - 1
            if self.ovr_counter == 0:
                self.ovr_counter = 1
            fields.append(f"WCO:{0:.{digits}f},{0:.{digits}f},{0:.{digits}f}")
        if self.ovr_counter > 0:
            self.ovr_counter -= 1
        else:
            self.ovr_counter = (20 if busy else 10) - 1
            fields.append(f"Ov:{self.feed_override},{self.rapid_override},100")
        return "<" + "|".join(fields) + ">"
