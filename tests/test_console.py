import time

from nerf_transporter.console import LineBar, progress_bar


def test_progress_in_a_log_is_plain_lines_with_the_count_and_pace(capsys):
    with progress_bar(3, "test episodes") as bar:  # capsys: stderr is no terminal, as in a log
        assert isinstance(bar, LineBar)
        for successes in (1, 1, 2):
            bar.set_postfix(successes=successes)
            bar.update(1)
    err = capsys.readouterr().err
    assert "\r" not in err
    (line,) = err.splitlines()  # nothing before the end: less than `every_s` went by
    assert line.startswith("test episodes: 3/3 episodes  successes 2  ")
    assert line.endswith(" s/episode")


def test_a_line_bar_writes_at_most_every_interval(capsys):
    bar = LineBar(100, "generate", initial=10, every_s=0.05)  # resumed: 10 episodes were there
    bar.update(1)
    bar.update(1)
    assert capsys.readouterr().err == ""
    time.sleep(0.06)
    bar.update(1)
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("generate: 13/100 episodes  ")  # pace over the 3 done here


def test_disabled_progress_writes_nothing(capsys):
    with progress_bar(2, "evaluation", enabled=False) as bar:
        bar.update(2)
    assert capsys.readouterr().err == ""
