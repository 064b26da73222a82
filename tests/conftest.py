"""Shared helpers: small simulated rigs."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import os

# One worker a core (pytest_xdist_auto_num_workers below): one BLAS thread each (rig/blas_threads.py), set before
# numpy is imported; the workers and the commands the tests start inherit it.
from rig.blas_threads import one_blas_thread  # noqa: E402
from rig.process_gc import collect_less_often, freeze_before_exit  # noqa: E402

one_blas_thread()
collect_less_often()  # as the `rig` program does (rig/process_gc.py): the workers' collector runs less often

import pytest


def _fail_skips_in_ci(report) -> None:
    """In CI everything the tests need is installed, so a skip means a broken set-up: fail it. An expected
    failure (xfail) is reported as skipped too, with `wasxfail`: that is no skip, and stays as it is."""
    if os.environ.get("CI") and report.skipped and not hasattr(report, "wasxfail"):
        report.outcome = "failed"
        report.longrepr = f"skipped in CI, where every dependency is installed: {report.longrepr}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _fail_skips_in_ci(outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    _fail_skips_in_ci(outcome.get_result())


#: what `--quick` (`python3 dev.py test --quick`, the inner loop) leaves out: controllers served in real time (serial
#: stages, the GRBL firmware), the blind diagnosis trials and crash trials, the TUI, and every test that took 2 s or
#: more of wall time on a loaded 2-core machine (measured per test, 2026-11-25). The full command runs them all.
SLOW_FILES = {
    "test_serial_stages.py", "test_zaber_protocol.py", "test_grbl_protocol.py", "test_grbl_firmware.py",
    "test_grbl_firmware_harness.py", "test_grbl_golden.py", "test_stage_runs.py",  # real time
    "test_diagnosis.py", "test_crash_safety.py", "test_recovery.py", "test_grouping.py",  # trials
    "test_tui.py", "test_tui_operator.py",  # the terminal UI
    "test_cli_flags.py", "test_cli_outputs.py", "test_cli_progress.py", "test_disk_full.py", "test_effects_guide.py",
    "test_fuzz_recordings.py", "test_readme.py", "test_undetermined.py",
    "test_enospc_injection.py", "test_kill_leftovers.py",  # the real command under strace, dozens of times
    "test_tiny_runs.py",  # two real commands, 4 s
    "test_independence.py", "test_ir_saturation.py", "test_bag_import.py",  # real recordings, small trials
}
SLOW_TESTS = {
    "test_cli.py": {"test_console_script_is_installed_and_runs", "test_demo_small", "test_run_then_fit"},
    "test_cli_json.py": {"test_diagnose", "test_fit_model_and_compare_share_the_fit_fields"},
    "test_analysis_papercuts.py": {"test_a_plot_file_matplotlib_cannot_write_is_refused_before_the_fit",
                                   "test_an_effect_the_data_do_not_show_sits_at_its_bound_and_says_so"},
    "test_device_kinds.py": {"test_rig_devices_prints_only_its_listing_on_stdout"},
    "test_effect_registry.py": {"test_the_diagnosis_finds_it_from_the_effects_flag"},
    "test_protocol_catalogue.py": {"test_the_tui_runs_a_protocol_registered_at_run_time",
                                   "test_ctrl_c_during_rig_run_exits_130_as_the_help_says"},
    "test_device_options.py": {"test_the_installed_command_exits_2_on_a_stage_typo"},
    "test_fit_many.py": {"test_a_reader_that_stops_early_ends_it_quietly"},
    "test_fuzz_inputs.py": {"test_experiment_files", "test_import_manifests", "test_serial_replies"},
    "test_import.py": {"test_fit_compare_and_diagnose_work_on_an_import", "test_import_gives_the_live_run_statistics_and_fit"},
    "test_models.py": {"test_noise_floor_recovered_and_lambda_back_to_three"},
    "test_oak.py": {"test_importing_the_driver_needs_no_sdk"},
    "test_paper_windows.py": {"test_cli_prints_one_table_and_conclusion_per_scenario",
                              "test_shot_noise_alone_gives_the_model_lambda_in_every_window",
                              "test_noise_floor_makes_active_lambda_rise"},
    "test_realsense.py": {"test_a_slow_reader_gets_every_frame_of_a_recording",
                          "test_importing_the_driver_needs_no_sdk_and_using_it_says_what_to_install",
                          "test_perpendicular_run_through_the_sdk_records_and_fits_like_the_fake_camera",
                          "test_recording_made_by_the_sdk_plays_back_with_the_same_per_pixel_statistics"},
    "test_reliability.py": {"test_a_second_writer_is_refused_with_who_holds_the_file", "test_sigterm_ends_a_run_like_ctrl_c"},
    "test_rounding.py": {"test_shipped_table_is_what_the_sums_give"},
    "test_user_effects.py": {"test_the_effects_flag_on_fit_and_compare"},
    "test_recordings_compared.py": {"test_a_fleet_on_a_dask_cluster_gives_what_the_local_pool_gives"},
}


def pytest_addoption(parser):
    parser.addoption("--quick", action="store_true",
                     help="the inner loop: leave out real-time, trial, TUI and slow tests (tests/conftest.py, SLOW_*)")


def is_slow(item) -> bool:
    path = Path(str(item.fspath)).name
    return path in SLOW_FILES or item.originalname in SLOW_TESTS.get(path, ())


def pytest_collection_modifyitems(config, items):
    if not config.getoption("--quick"):
        return
    slow = [item for item in items if is_slow(item)]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if not is_slow(item)]


def pytest_unconfigure(config):
    """The session is over (in each xdist worker and in the controller): what it made is frozen, so the
    interpreter's shutdown collections pass over nothing (rig/process_gc.py)."""
    freeze_before_exit()


def pytest_xdist_auto_num_workers(config):
    """`-n auto`: one worker a core. Two a core finished sooner (the serial-stage tests run GRBL and Zaber
    controllers in real time and mostly wait: 5 min 23 s against 6 min 4 s, measured on 2 cores in 2026-11), but
    every CPU-bound test then shares its core and its caches with another and takes more CPU to do the same work:
    tests/test_diagnosis.py + tests/test_recovery.py took 191-210 s of the machine's CPU with 4 workers and 166-183 s
    with 2, and the whole `.ci/run` from a fresh clone 1,003 s with 4 and 898 s with 2 (2026-11-26, the same
    commit back to back; 10 min 16 s and 13 min 0 s of wall time). The suite is held to a CPU budget (10 min),
    not to its wall time (20 min), so one worker a core."""
    import os

    return os.cpu_count() or 1


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory) -> Path:
    """The small recording the CLI tests read and never change: a perpendicular run of the fake camera, 32 px
    wide, 8 frames a stop at 0.5, 1.0, 1.5 and 2.0 m, exposure 3300 us, gain 32. Made once for all the xdist
    workers of a run (under a lock in the temp folder they share), not once a module."""
    import fcntl

    from simrig import record_perpendicular

    root = tmp_path_factory.getbasetemp().parent  # one per pytest run, shared by its workers
    path = root / "small-recording" / "four-stops.h5"
    path.parent.mkdir(exist_ok=True)
    with open(root / "small-recording.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not path.exists():
            making = path.parent / "making" / "four-stops.h5"
            making.parent.mkdir(exist_ok=True)
            record_perpendicular(making, width=32, frames=8, stops_m=[0.5, 1.0, 1.5, 2.0], exposure_us=3300.0,
                                 gain=32.0)
            making.rename(path)
    return path
