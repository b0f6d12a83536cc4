from nerf_transporter.console import LineBar, progress_bar


class StepClock:
    """A clock that moves only when told: the seconds `advance` adds."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


def test_progress_in_a_log_is_plain_lines_with_the_count_and_pace(capsys):
    with progress_bar(3, "test episodes") as bar:  # capsys: stderr is no terminal, as in a log
        assert isinstance(bar, LineBar) and bar.every_s == 30.0
    clock = StepClock()
    with LineBar(3, "test episodes", clock=clock) as bar:
        for successes in (1, 1, 2):
            clock.advance(2.5)
            bar.set_postfix(successes=successes)
            bar.update(1)
    err = capsys.readouterr().err
    assert "\r" not in err
    (line,) = err.splitlines()  # nothing before the end: 7.5 s is less than `every_s`
    assert line == "test episodes: 3/3 episodes  successes 2  2.5 s/episode"


def test_a_line_bar_writes_at_most_every_interval(capsys):
    clock = StepClock()
    bar = LineBar(100, "generate", initial=10, every_s=30.0, clock=clock)  # resumed: 10 were there
    clock.advance(10.0)
    bar.update(1)
    clock.advance(19.9)
    bar.update(1)
    assert capsys.readouterr().err == ""  # 29.9 s: not yet
    clock.advance(0.1)
    bar.update(1)
    (line,) = capsys.readouterr().err.splitlines()
    assert line == "generate: 13/100 episodes  10.0 s/episode"  # pace over the 3 done here
    clock.advance(29.0)
    bar.update(1)
    assert capsys.readouterr().err == ""  # the interval counts from the last line written
    clock.advance(1.0)
    bar.update(1)
    assert capsys.readouterr().err == "generate: 15/100 episodes  12.0 s/episode\n"


def test_disabled_progress_writes_nothing(capsys):
    with progress_bar(2, "evaluation", enabled=False) as bar:
        bar.update(2)
    assert capsys.readouterr().err == ""
