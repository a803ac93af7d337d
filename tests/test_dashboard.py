"""The operator dashboard in headless Chromium (Debian's), against ``serve`` on the
embedded simulator."""

from __future__ import annotations

import asyncio
import math
import os
import re
import shutil
import signal
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path

import httpx
import pytest
from playwright.async_api import Browser, Page, ViewportSize, async_playwright, expect

from benchmarks.service import (
    RunningService,
    all_connected,
    all_disarmed,
    in_mode,
    position_m,
    running_service,
)
from supervisor.flight.modes import Mode
from supervisor.flight.status import ArenaBox
from tests.test_agents_e2e import agents_alive
from tests.test_px4_sitl import PX4_REFUSAL, require_gps_for_arming
from tests.test_service import require_px4

CHROMIUM = shutil.which("chromium")
# Written where git does not see them; copied into docs/images by hand once looked at.
IMAGES = Path(__file__).resolve().parent.parent / "build" / "screenshots"
SCREENSHOT = IMAGES / "dashboard.png"
DESKTOP = ViewportSize(width=1500, height=1000)
SMALL = ViewportSize(width=1024, height=700)
TOKEN = "dashboard-token-0123"
PAGE_ERRORS: list[str] = []

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed"),
]


@pytest.fixture
async def browser() -> AsyncIterator[Browser]:
    """Chromium at the usual priority: serve's world, flight and relay processes run at
    real-time priority where they may (as in CI), which a browser cannot starve; a niced
    browser was starved instead by the other test worker, its clicks timing out. WebGL
    without a GPU is SwiftShader's (software), which Chromium gives only when asked for."""
    assert CHROMIUM is not None
    async with async_playwright() as playwright:
        chromium = await playwright.chromium.launch(
            executable_path=CHROMIUM,
            args=["--no-sandbox", "--enable-unsafe-swiftshader"],
            headless=True,
        )
        yield chromium
        await chromium.close()


async def open_dashboard(
    browser: Browser, service: RunningService, token: str, viewport: ViewportSize = DESKTOP
) -> Page:
    async with service.client() as http:
        await service.wait_for(http, all_connected, 60.0, "healthy mocap and both links")
    page = await browser.new_page(viewport=viewport)
    page.on("pageerror", lambda error: PAGE_ERRORS.append(str(error)))
    await page.goto(f"{service.url}/#token={token}")
    connection = page.get_by_test_id("connection")
    # "live again" after a pause in telemetry of a busy machine's making
    await expect(connection).to_have_text(re.compile("connected|live again"), timeout=20_000)
    # Live telemetry: the mode shows, and the mocap lamp turns healthy.
    await expect(page.get_by_test_id("mode")).to_have_text("disarmed")
    await expect(page.locator("#lamp-mocap")).to_have_class(re.compile("good"), timeout=20_000)
    await expect(page.locator("#lamp-uav2")).to_have_class(re.compile("good"), timeout=20_000)
    assert "token" not in page.url  # the fragment is removed from the address bar
    return page


COLOUR_PIXELS_JS = """([selector, rgb, below]) => {
    const source = document.querySelector(selector);
    const copy = document.createElement("canvas");
    copy.width = source.width;
    copy.height = source.height;
    const g = copy.getContext("2d");
    g.drawImage(source, 0, 0);
    const ratio = source.width / source.getBoundingClientRect().width;
    const data = g.getImageData(0, 0, copy.width, copy.height).data;
    let n = 0, sx = 0, sy = 0;
    for (let i = 0; i < data.length; i += 4) {
        const [x, y] = [(i / 4) % copy.width, Math.floor(i / 4 / copy.width)];
        const off = [0, 1, 2].reduce((sum, c) => sum + Math.abs(data[i + c] - rgb[c]), 0);
        if (y >= below * ratio && off < 40) { n += 1; sx += x; sy += y; }
    }
    return { count: n, x: n ? sx / n / ratio : null, y: n ? sy / n / ratio : null };
}"""
UAV1_BLUE, UAV2_VIOLET = (0x4E, 0xA1, 0xFF), (0xC5, 0x8B, 0xFF)


async def colour_pixels(
    page: Page, selector: str, rgb: tuple[int, int, int], below_px: float = 0.0
) -> dict[str, float]:
    """How many pixels of the canvas at ``selector`` (those ``below_px`` CSS pixels or more
    from its top) are near ``rgb``, and their centroid in CSS pixels from the canvas's top
    left: what was drawn, WebGL or 2D."""
    arguments = [selector, list(rgb), below_px]
    result: dict[str, float] = await page.evaluate(COLOUR_PIXELS_JS, arguments)
    return result


async def take_off(page: Page) -> None:
    await page.get_by_test_id("arm").click()
    await expect(page.get_by_test_id("mode")).to_have_text("armed", timeout=10_000)
    await page.get_by_test_id("takeoff").click()
    await expect(page.get_by_test_id("mode")).to_have_text("hover", timeout=60_000)


async def test_dashboard_shows_telemetry_refuses_a_bad_token_and_aborts(
    browser: Browser, tmp_path: Path
) -> None:
    # A swing hand-over angle below a hover's own wobble, so that the page has a safety
    # notice to show: the decentralized MPC is handed back to the centralized one at once.
    hand_over_at_once = ["safety.max_bar_yaw_error_deg=0.2"]
    async with running_service(TOKEN, tmp_path, hand_over_at_once) as service:
        page = await open_dashboard(browser, service, "not-the-token")
        await expect(page.get_by_test_id("agent-row")).to_be_hidden()  # one flight process
        await page.get_by_test_id("arm").click()
        await expect(page.get_by_test_id("flight-reason")).to_contain_text("401")
        await expect(page.get_by_test_id("mode")).to_have_text("disarmed")

        # The refused token was dropped; the next command asks for it once.
        page.once("dialog", lambda dialog: dialog.dismiss())
        await page.get_by_test_id("arm").click()
        await page.get_by_test_id("token-input").fill(TOKEN)
        await page.get_by_test_id("token-ok").click()
        await expect(page.get_by_test_id("mode")).to_have_text("armed", timeout=10_000)
        await page.get_by_test_id("takeoff").click()
        await expect(page.get_by_test_id("mode")).to_have_text("hover", timeout=60_000)
        await page.get_by_test_id("controller-decentralized").click()
        notices = page.get_by_test_id("notices")
        await expect(notices).to_contain_text("switched to the centralized MPC", timeout=20_000)
        await expect(notices).to_contain_text(re.compile(r"\d+ s ago — swing: bar yaw"))
        await expect(page.get_by_test_id("controller")).to_have_text("centralized")
        await page.wait_for_timeout(3000)  # a few seconds of live plots for the picture
        await page.screenshot(path=str(SCREENSHOT))

        banner = page.get_by_test_id("banner")
        await expect(banner).to_be_hidden()  # a hover after a hand-over is normal flight
        await page.get_by_test_id("mode").click()  # focus anywhere; Escape aborts
        await page.keyboard.press("Escape")
        await expect(page.get_by_test_id("mode")).to_have_text(re.compile("abort"))
        # No safety monitor asked for it: the banner says who can have.
        await expect(page.get_by_test_id("banner-title")).to_have_text("ABORT")
        await expect(page.get_by_test_id("banner-text")).to_contain_text("asked for with ABORT")
        await expect(page.get_by_test_id("abort-reason")).to_have_text("accepted")
        await expect(page.get_by_test_id("abort-reason")).to_have_text("", timeout=10_000)
        await expect(page.get_by_test_id("mode")).to_have_text("disarmed", timeout=90_000)
        await expect(banner).to_be_hidden()
        async with service.client() as http:
            status = await service.wait_for(http, all_disarmed, 10.0, "vehicles disarmed")
        assert position_m(status.bar.position)[2] < 0.05
        assert not PAGE_ERRORS, PAGE_ERRORS


async def test_each_agent_is_shown_and_a_killed_one_said_lost(
    browser: Browser, tmp_path: Path
) -> None:
    """With agents.enabled the vehicles table has an agent row: each vehicle's agent, its
    process id and round trip; agent 2 killed, its cell says lost, in the lost colour,
    and agent 1's does not."""
    async with running_service(TOKEN, tmp_path, ["agents.enabled=true"]) as service:
        async with service.client() as http:
            status = await service.wait_for(http, agents_alive, 60.0, "both agents heard")
        assert status.agents is not None
        page = await open_dashboard(browser, service, TOKEN)
        await expect(page.get_by_test_id("agent-row")).to_be_visible()
        for agent in status.agents:
            cell = page.get_by_test_id(f"uav{agent.vehicle}-agent")
            await expect(cell).to_have_text(re.compile(rf"pid {agent.pid}, \d+\.\d ms$"))
        killed = status.agents[1].pid
        assert killed is not None
        os.kill(killed, signal.SIGKILL)
        lost = page.get_by_test_id("uav2-agent")
        await expect(lost).to_have_text(re.compile(rf"^lost \(.*pid {killed}, heard "))
        await expect(lost).to_have_class(re.compile(r"\blost\b"))
        await expect(page.get_by_test_id("uav1-agent")).not_to_have_class(re.compile("lost"))
        assert not PAGE_ERRORS, PAGE_ERRORS


async def test_switch_controller_and_queue_a_setpoint_from_the_page(
    browser: Browser, tmp_path: Path
) -> None:
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, TOKEN)
        await take_off(page)
        # Each UAV's battery, in the table and plotted over the last 20 s.
        for n in (1, 2):
            await expect(page.get_by_test_id(f"uav{n}-battery")).to_have_text(
                re.compile(r"^1[0-9]\.\d V$")
            )
        for colour in (UAV1_BLUE, UAV2_VIOLET):  # the lines, below the legend
            drawn = await colour_pixels(page, "#battery-plot", colour, below_px=20)
            assert drawn["count"] > 50, drawn
        await page.get_by_test_id("controller-decentralized").click()
        await expect(page.get_by_test_id("controller")).to_have_text("decentralized")
        form = page.get_by_test_id("setpoint-form")
        await form.locator("input[name=x]").fill("0.4")
        await form.locator("input[name=y]").fill("-0.2")
        await form.locator("input[name=z]").fill("1.1")
        equilibrium = page.get_by_test_id("equilibrium")
        await form.locator("input[name=theta_l]").fill("86")  # beyond the setup's bounds
        await expect(equilibrium).to_contain_text("would be refused: θ_l 86.0° exceeds")
        await expect(equilibrium).to_have_class(re.compile("blocked"))
        await form.locator("input[name=theta_l]").fill("20")
        await expect(equilibrium).to_contain_text("θf")
        await expect(equilibrium).not_to_contain_text("refused")
        await page.get_by_test_id("queue-setpoint").click()
        await expect(page.get_by_test_id("setpoint-reason")).to_have_text("accepted")
        active = page.get_by_test_id("active-setpoint")
        await expect(active).to_contain_text("0.40, -0.20, 1.10", timeout=15_000)

        # A setpoint outside the arena is refused, with the reason next to the form.
        await form.locator("input[name=z]").fill("2.9")
        await page.get_by_test_id("queue-setpoint").click()
        await expect(page.get_by_test_id("setpoint-reason")).to_contain_text("outside the arena")

        # The bar reaches it in the view (to the centimetres the page shows: ±0.1 m).
        position = page.get_by_test_id("bar-position")
        near = re.compile(r"\(0\.[3-5]\d, -0\.[1-3]\d, 1\.[01]\d\)")
        await expect(position).to_have_text(near, timeout=40_000)
        await page.get_by_test_id("land").click()
        await expect(page.get_by_test_id("mode")).to_have_text("disarmed", timeout=90_000)
        assert not PAGE_ERRORS, PAGE_ERRORS


ABORT_SENT_WITHIN_S = 0.5  # the request's round trip, with a margin for a busy machine


async def press_abort_from_a_hover(
    page: Page, service: RunningService, press: Callable[[], Awaitable[None]]
) -> float:
    """Take off over HTTP, ``press`` ABORT on the page; the abort request's round trip [s]
    (the flight process's reply included), once the system has landed and disarmed."""
    async with service.client() as http:
        await service.take_off(http)
        async with page.expect_response("**/api/abort") as answered:
            await press()
        response = await answered.value
        assert response.status == 200, await response.text()
        await expect(page.get_by_test_id("mode")).to_have_text(re.compile("abort|disarmed"))
        await service.wait_for(http, all_disarmed, 90.0, "disarmed")
        (await http.post("/api/sim/reset")).raise_for_status()  # the resting pose again
    return float(response.request.timing["responseEnd"]) / 1000.0


async def test_abort_lands_the_system_without_a_token_with_a_wrong_one_and_the_dialog_open(
    browser: Browser, tmp_path: Path
) -> None:
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, "not-the-token")
        abort_button = page.get_by_test_id("abort")
        dialog = page.get_by_test_id("token-dialog")
        round_trips = {}

        round_trips["wrong token"] = await press_abort_from_a_hover(
            page, service, abort_button.click
        )
        await page.evaluate("sessionStorage.clear()")
        round_trips["no token"] = await press_abort_from_a_hover(page, service, abort_button.click)

        async def with_the_dialog_open() -> None:
            await page.get_by_test_id("land").click()  # no token: the dialog asks for one
            await expect(dialog).to_be_visible()
            await abort_button.click()

        round_trips["dialog open"] = await press_abort_from_a_hover(
            page, service, with_the_dialog_open
        )
        await expect(dialog).to_be_hidden()  # ABORT closed it; the land was not sent
        await expect(page.get_by_test_id("flight-reason")).to_have_text(
            "no token: the command was not sent"
        )

        # Escape closes the dialog too (and aborts: accepted on the ground as well).
        await page.get_by_test_id("arm").click()
        await expect(dialog).to_be_visible()
        await page.keyboard.press("Escape")
        await expect(dialog).to_be_hidden()
        await expect(page.locator("#abort-reason")).to_have_text("accepted")
        assert all(t < ABORT_SENT_WITHIN_S for t in round_trips.values()), round_trips
        assert not PAGE_ERRORS, PAGE_ERRORS


async def test_a_refused_token_is_kept_and_said(browser: Browser, tmp_path: Path) -> None:
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, "not-the-token")
        await page.get_by_test_id("arm").click()
        await expect(page.get_by_test_id("flight-reason")).to_contain_text("not valid")
        assert await page.evaluate("sessionStorage.getItem('uavbar-token')") == "not-the-token"
        await page.get_by_test_id("arm").click()  # asks, saying why
        await expect(page.locator("#token-note")).to_contain_text("refused (401)")
        await page.get_by_test_id("token-cancel").click()
        await expect(page.get_by_test_id("token-dialog")).to_be_hidden()
        assert await page.evaluate("sessionStorage.getItem('uavbar-token')") == "not-the-token"
        await expect(page.get_by_test_id("mode")).to_have_text("disarmed")


async def test_a_stall_of_the_simulated_world_is_said_to_be_this_computers(
    browser: Browser, tmp_path: Path
) -> None:
    """The world process held for 0.4 s in a hover, as a busy computer holds it: the mocap
    gap hands the flight to PX4's landing, and the page says that this computer stalled the
    simulated world, for how long, that a gap then is not the lab's, and (in the banner)
    that the stall came just before the hand-over."""
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, TOKEN)
        await take_off(page)
        world = service.child_pid("uavbar-world")
        os.kill(world, signal.SIGSTOP)
        await asyncio.sleep(0.4)
        os.kill(world, signal.SIGCONT)
        stalls = page.get_by_test_id("world-stalls")
        at_least_300_ms = re.compile(r"the last for ([3-9]\d\d|\d{4,}) ms .* not the lab's")
        await expect(stalls).to_have_text(at_least_300_ms, timeout=10_000)
        await expect(page.get_by_test_id("mode")).to_have_text("px4_landing")
        banner = page.get_by_test_id("banner-text")
        await expect(banner).to_contain_text("the simulated world had stalled")
        assert not PAGE_ERRORS, PAGE_ERRORS


@pytest.mark.px4
async def test_a_refused_arm_shows_px4s_own_reason_on_the_page(
    browser: Browser, tmp_path: Path
) -> None:
    """Two real PX4s that require GPS refuse to arm: the page's reason, its notices and
    each "PX4 says" row carry PX4's own words."""
    require_px4()
    async with running_service(TOKEN, tmp_path, ['sim.vehicles="px4_sitl"']) as service:
        page = await open_dashboard(browser, service, TOKEN)
        await require_gps_for_arming(service)
        await page.get_by_test_id("arm").click()
        await expect(page.get_by_test_id("flight-reason")).to_have_text(PX4_REFUSAL)
        await expect(page.get_by_test_id("notices")).to_contain_text(PX4_REFUSAL)
        px4_text = re.compile("Arming denied|Preflight Fail")
        for row in ("#uav1-text", "#uav2-text"):
            await expect(page.locator(row)).to_have_text(px4_text, timeout=10_000)
        await expect(page.get_by_test_id("mode")).to_have_text("disarmed")
        assert not PAGE_ERRORS, PAGE_ERRORS


async def test_a_monitors_abort_a_lost_link_and_a_lost_stream_are_shown_as_such(
    browser: Browser, tmp_path: Path
) -> None:
    """A vehicle's link lost in a hover: the page turns red, says what the supervisor does
    and why (the notice), greys what came from that link; the API process killed: every
    value greyed, the last mode no longer bold, until the stream is back."""
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, TOKEN)
        mode = page.get_by_test_id("mode")
        tick_lamp = page.get_by_test_id("lamp-tick")
        await expect(tick_lamp).to_have_class(re.compile("good"), timeout=20_000)
        await expect(tick_lamp).to_have_attribute("title", re.compile("Now: on time"))
        await expect(page.get_by_test_id("lamp-mocap")).to_have_attribute(
            "title", re.compile("Now: healthy")
        )

        # The bar unseen while disarmed: the mocap lamp turns yellow, the bar's values are
        # greyed, and the page says why an arm would be refused now, until it is seen again.
        async with service.client() as http:
            lost = {"kind": "mocap_body_lost", "body": "bar", "duration_s": 3.0}
            (await http.post("/api/sim/faults", json=lost)).raise_for_status()
        blocked = page.get_by_test_id("arm-blocked")
        await expect(blocked).to_contain_text("Arm would be refused now: no fresh motion capture")
        await expect(page.get_by_test_id("arm")).to_have_class(re.compile("blocked"))
        await expect(page.get_by_test_id("lamp-mocap")).to_have_class(re.compile("warn"))
        await expect(page.get_by_test_id("bar-position")).to_have_class(re.compile("stale-value"))
        await expect(blocked).to_have_text("", timeout=20_000)
        await expect(page.get_by_test_id("bar-position")).not_to_have_class(
            re.compile("stale-value")
        )

        os.kill(service.child_pid("uavbar-api"), signal.SIGKILL)
        await expect(page.get_by_test_id("connection")).to_have_text(re.compile("lost"))
        await expect(page.get_by_test_id("banner-title")).to_have_text("NO LIVE DATA")
        await expect(page.get_by_test_id("banner-text")).to_contain_text(re.compile(r"\d+ s old"))
        assert await mode.evaluate("e => getComputedStyle(e).fontWeight") == "400"
        assert await page.locator("#lamp-uav1").get_attribute("class") == "lamp unknown"
        await expect(page.get_by_test_id("connection")).to_have_text("live again", timeout=30_000)
        await expect(page.get_by_test_id("banner")).to_be_hidden()
        assert await mode.evaluate("e => getComputedStyle(e).fontWeight") == "700"

        async with service.client() as http:
            await service.take_off(http)
            # Until cleared: what the page shows is checked while the link is still lost.
            answer = await http.post("/api/sim/faults", json={"kind": "link_lost", "vehicle": 1})
            answer.raise_for_status()
            await expect(page.get_by_test_id("banner-title")).to_have_text("ABORT")
            await expect(page.get_by_test_id("banner-text")).to_contain_text(
                "why: land_other: vehicle 1 link lost"
            )
            assert await page.get_by_test_id("banner").get_attribute("class") == "banner bad"
            await expect(mode).to_have_attribute("data-level", "bad")
            lamp = page.get_by_test_id("lamp-uav1")
            await expect(lamp).to_have_class(re.compile("bad"))
            await expect(lamp).to_have_attribute("title", re.compile("LOST"))
            await expect(page.get_by_test_id("uav1-px4")).to_have_class(re.compile("stale-value"))
            await expect(page.get_by_test_id("uav2-px4")).not_to_have_class(
                re.compile("stale-value")
            )
            await expect(page.get_by_test_id("uav1-px4")).to_contain_text("(link lost)")
            (await http.delete("/api/sim/faults")).raise_for_status()
            await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "landed")
            await expect(page.get_by_test_id("banner")).to_be_hidden()
            await expect(page.get_by_test_id("notices")).to_contain_text("vehicle 1 link lost")
        assert not PAGE_ERRORS, PAGE_ERRORS


IN_SIGHT = ("abort", "mode", "lamp-tick", "top-view", "side-view", "arm", "land", "setpoint-form")
APART = ("top", "views", "flight-panel", "setpoint-panel")


async def assert_laid_out(page: Page, viewport: ViewportSize) -> None:
    """The controls, both views and the setpoint form inside the window; the header, the
    views and the two panels side by side, none over another; no sideways scrolling."""
    # All boxes read in one script, from one layout: read one by one, a notice that came
    # in between grew the header under the views already measured.
    boxes = await page.evaluate(
        """names => Object.fromEntries(names.map(name => {
            const found = name === "top" ? document.getElementById(name)
                : document.querySelector(`[data-testid="${name}"]`);
            const box = found?.getBoundingClientRect();
            return [name, box && box.width > 0 && box.height > 0
                ? {x: box.x, y: box.y, width: box.width, height: box.height} : null];
        }))""",
        [*IN_SIGHT, *APART],
    )
    for name, box in boxes.items():
        assert box is not None, f"{name} is not laid out"
    for name in IN_SIGHT:
        b = boxes[name]
        inside = b["x"] >= 0 and b["y"] >= 0
        inside &= b["x"] + b["width"] <= viewport["width"]
        inside &= b["y"] + b["height"] <= viewport["height"]
        assert inside, f"{name} is not inside the {viewport} window: {b}"
    for i, first in enumerate(APART):
        for second in APART[i + 1 :]:
            a, b = boxes[first], boxes[second]
            apart = a["x"] + a["width"] <= b["x"] or b["x"] + b["width"] <= a["x"]
            apart |= a["y"] + a["height"] <= b["y"] or b["y"] + b["height"] <= a["y"]
            if not apart:
                scrolled = await page.evaluate("window.scrollY")
                raise AssertionError(f"{first} {a} overlaps {second} {b} (scrolled {scrolled} px)")
    width = await page.evaluate("document.scrollingElement.scrollWidth")
    assert width <= viewport["width"], f"the page scrolls sideways: {width} px wide"


async def test_the_layout_at_1024_by_700_keeps_the_views_and_the_setpoints_in_sight(
    browser: Browser, tmp_path: Path
) -> None:
    """Checked on the page's boxes in a hover and in an abort (its banner and notice make
    the header taller); the README's screenshots of both, small and desktop."""
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, TOKEN, SMALL)
        await assert_laid_out(page, SMALL)
        async with service.client() as http:
            await service.take_off(http)
            await expect(page.get_by_test_id("mode")).to_have_text("hover")
            await assert_laid_out(page, SMALL)
            await page.wait_for_timeout(2000)  # some live plot for the picture
            await page.screenshot(path=str(IMAGES / "dashboard-1024.png"))

            fault = {"kind": "link_lost", "vehicle": 1}  # until cleared: the abort lasts
            (await http.post("/api/sim/faults", json=fault)).raise_for_status()
            await expect(page.get_by_test_id("banner-text")).to_contain_text("why: land_other")
            await page.screenshot(path=str(IMAGES / "dashboard-1024-abort.png"))
            await assert_laid_out(page, SMALL)
            await page.set_viewport_size(DESKTOP)
            await expect(page.get_by_test_id("mode")).to_have_text("abort")
            await page.screenshot(path=str(IMAGES / "dashboard-abort.png"))
            await assert_laid_out(page, DESKTOP)
            (await http.delete("/api/sim/faults")).raise_for_status()
            await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "landed")
        assert not PAGE_ERRORS, PAGE_ERRORS


BAR_ORANGE, MAJOR_GRID = (0xF0, 0xA0, 0x30), (0x46, 0x52, 0x5E)
DRAWN_WITHIN_PX = 10.0


async def bar_drawn_and_projected(
    page: Page, service: RunningService, http: httpx.AsyncClient
) -> tuple[dict[str, float], list[float]]:
    """The 3D view's orange pixels (the bar) and where the view's camera puts the bar's
    estimated middle (from ``/api/status``), in CSS pixels from the canvas's top left."""
    position = (await service.status(http)).bar.position
    await page.wait_for_timeout(500)  # a few messages drawn since
    drawn = await colour_pixels(page, "#view3d", BAR_ORANGE)
    projected: list[float] = await page.evaluate("p => window.uavbarView3d.project(p)", position)
    return drawn, projected


async def test_the_3d_view_draws_the_arena_and_follows_the_bar(
    browser: Browser, tmp_path: Path
) -> None:
    """WebGL (SwiftShader) in headless Chromium: the arena's grid is drawn, and the bar is
    drawn where its estimate is, resting and then hovering a metre higher."""
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, TOKEN)
        view = page.get_by_test_id("view3d")
        await expect(view).to_have_attribute("data-renders", re.compile(r"^[1-9]"))
        await expect(page.get_by_test_id("view3d-note")).to_have_text("")
        assert await page.evaluate("window.uavbarView3d.webgl") in ("webgl", "webgl2")
        assert (await colour_pixels(page, "#view3d", MAJOR_GRID))["count"] > 500

        async with service.client() as http:
            resting, projected = await bar_drawn_and_projected(page, service, http)
            assert resting["count"] > 30, resting
            off = math.dist((resting["x"], resting["y"]), projected)
            assert off < DRAWN_WITHIN_PX, (resting, projected)

            await service.take_off(http)
            hovering, projected = await bar_drawn_and_projected(page, service, http)
            assert hovering["count"] > 30, hovering
            off = math.dist((hovering["x"], hovering["y"]), projected)
            assert off < DRAWN_WITHIN_PX, (hovering, projected)
            assert resting["y"] - hovering["y"] > 20, (resting, hovering)  # drawn higher up
            box = await page.get_by_test_id("view3d").bounding_box()
            assert box is not None
            await page.screenshot(path=str(IMAGES / "dashboard-3d.png"), clip=box)
            (await http.post("/api/land")).raise_for_status()
            await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "landed")
        assert not PAGE_ERRORS, PAGE_ERRORS


MEDIUM = ViewportSize(width=1280, height=800)
WIDE = ViewportSize(width=1920, height=1080)
# In sight without scrolling from 1280 × 800 up: the flight controls, the bar's state and
# a plot; where the page says why an arm would be refused or the log stopped.
CONTROLS = (
    "abort", "mode", "arm", "takeoff", "land", "disarm", "kill-box",
    "controller-centralized", "controller-decentralized",
)  # fmt: skip
BAR_STATE = ("bar-position", "bar-error")
SAID_HERE = ("arm-blocked", "log-stopped", "flight-reason")
ARENA_EDGE = (0x5C, 0x6A, 0x78)  # the views' outline of the arena
LABELS_OUTSIDE_M = 0.5  # the 3D view's metre labels stand this far outside the arena

ARENA_DRAWN_JS = """(selector) => {
    const canvas = document.querySelector(selector);
    const drawn = JSON.parse(canvas.dataset.arena);
    const box = canvas.getBoundingClientRect();
    const ratio = canvas.width / box.width;
    const g = canvas.getContext("2d");
    const corners = [[drawn.left, drawn.top], [drawn.right, drawn.top],
                     [drawn.left, drawn.bottom], [drawn.right, drawn.bottom]];
    return {
        drawn, canvas: { width: box.width, height: box.height },
        // what is on top at each corner of the drawn arena, just inside it, in the window
        // (null outside the window)
        onTop: corners.map(([x, y]) => {
            const inward = [x === drawn.left ? 2 : -2, y === drawn.top ? 2 : -2];
            const [left, top] = [box.left + x + inward[0], box.top + y + inward[1]];
            return document.elementFromPoint(left, top) === canvas;
        }),
        // the colour drawn on each corner (the outline is 2 px wide, centred on it)
        colours: corners.map(([x, y]) => {
            const pixel = g.getImageData(Math.floor(x * ratio), Math.floor(y * ratio), 1, 1);
            return Array.from(pixel.data.slice(0, 3));
        }),
    };
}"""


# One synchronous read of the layout: the page redraws 25 times a second, and a line that
# appears between two reads (a refusal's reason, say) moved the buttons in between.
BOX_AND_ON_TOP_JS = """e => {
    const r = e.getBoundingClientRect();
    const middle = [r.left + r.width / 2, r.top + r.height / 2];
    return {
        box: {x: r.left, y: r.top, width: r.width, height: r.height},
        middle: middle,
        onTop: e.contains(document.elementFromPoint(middle[0], middle[1])),
    };
}"""


async def assert_in_sight(page: Page, viewport: ViewportSize, names: tuple[str, ...]) -> None:
    """Each element inside the window and not under another one (its middle is its own)."""
    for name in names:
        element = page.get_by_test_id(name)
        seen = await element.evaluate(BOX_AND_ON_TOP_JS)
        box = seen["box"]
        assert box["width"] > 0 and box["height"] > 0, f"{name} is not laid out"
        inside = box["x"] >= 0 and box["y"] >= 0
        inside &= box["x"] + box["width"] <= viewport["width"]
        inside &= box["y"] + box["height"] <= viewport["height"]
        assert inside, f"{name} is not inside the {viewport} window: {box}"
        assert seen["onTop"], f"{name} is under another element at {seen['middle']}"


async def assert_whole_arena_drawn(page: Page, arena: ArenaBox) -> None:
    """The top and side views draw the status's whole arena, inside their canvases and in
    the window with nothing over it; the 3D view draws it (labels included) uncut."""
    for selector, axes in (("#top-view", (0, 1)), ("#side-view", (0, 2))):
        seen = await page.evaluate(ARENA_DRAWN_JS, selector)
        drawn, canvas = seen["drawn"], seen["canvas"]
        assert drawn["min"] == [arena.min[a] for a in axes], (selector, drawn, arena)
        assert drawn["max"] == [arena.max[a] for a in axes], (selector, drawn, arena)
        assert 0 <= drawn["left"] < drawn["right"] <= canvas["width"], (selector, seen)
        assert 0 <= drawn["top"] < drawn["bottom"] <= canvas["height"], (selector, seen)
        assert all(seen["onTop"]), f"{selector}: a corner of the arena is out of sight: {seen}"
        for colour in seen["colours"]:
            off = sum(abs(c - e) for c, e in zip(colour, ARENA_EDGE, strict=True))
            assert off < 30, f"{selector}: no outline drawn at a corner: {seen}"
    canvas = await page.get_by_test_id("view3d").bounding_box()
    assert canvas is not None
    lo, hi, m = arena.min, arena.max, LABELS_OUTSIDE_M
    xs, ys, zs = (lo[0] - m, hi[0] + m), (lo[1] - m, hi[1] + m), (lo[2], hi[2])
    corners = [[x, y, z] for x in xs for y in ys for z in zs]
    for corner in corners:
        x, y = await page.evaluate("p => window.uavbarView3d.project(p)", corner)
        inside = 0 <= x <= canvas["width"] and 0 <= y <= canvas["height"]
        assert inside, f"the 3D view cuts {corner} off: drawn at {x, y} in {canvas}"


async def assert_the_operator_sees_it(page: Page, viewport: ViewportSize, arena: ArenaBox) -> None:
    await assert_in_sight(page, viewport, (*CONTROLS, *BAR_STATE, "error-plot", "view3d"))
    await assert_in_sight(page, viewport, ("top-view", "side-view"))
    for name in SAID_HERE:  # empty lines have no height: their place is in sight
        box = await page.get_by_test_id(name).bounding_box()
        assert box is not None and 0 <= box["y"] <= viewport["height"] - 20, (name, box)
    if await page.get_by_test_id("reset").is_visible():
        await assert_in_sight(page, viewport, ("reset",))
    await assert_whole_arena_drawn(page, arena)
    width = await page.evaluate("document.scrollingElement.scrollWidth")
    assert width <= viewport["width"], f"the page scrolls sideways: {width} px wide"


# How the page looks: its flight state, the mode's level, the header's and the mode's colours
# as drawn, and whether the last-flight line is shown.
LOOK_JS = """() => ({
    flight: document.body.dataset.flight,
    level: document.getElementById("mode").dataset.level,
    header: getComputedStyle(document.querySelector("header")).backgroundColor,
    mode: getComputedStyle(document.getElementById("mode")).backgroundColor,
    lastFlight: !document.getElementById("last-flight").hidden,
})"""


async def test_the_controls_bar_and_plots_in_sight_and_armed_disarmed_aborted_distinct(
    browser: Browser, tmp_path: Path
) -> None:
    """At 1280 × 800 and 1920 × 1080 (from the page's boxes): the flight controls, the
    bar's state, a plot and both views in the window, the top and side views drawing the
    whole arena and the 3D view not cutting it. Disarmed, armed on the ground and disarmed
    after an abort each look different, the last with a line saying so until the next
    arm. Reset is offered (embedded world) only while disarmed. The README's screenshots."""
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, TOKEN, MEDIUM)
        async with service.client() as http:
            arena = (await service.status(http)).arena
        mode, reset, reason = (page.get_by_test_id(n) for n in ("mode", "reset", "flight-reason"))
        last_flight = page.get_by_test_id("last-flight")
        await expect(reset).to_be_visible()
        await assert_the_operator_sees_it(page, MEDIUM, arena)
        disarmed = await page.evaluate(LOOK_JS)
        assert disarmed["flight"] == "disarmed" and not disarmed["lastFlight"], disarmed

        await reset.click()
        await expect(reason).to_contain_text(re.compile("^world reset: the motion capture tracks"))
        await expect(page.get_by_test_id("arm-blocked")).to_have_text("", timeout=30_000)
        await page.get_by_test_id("arm").click()
        await expect(mode).to_have_text("armed", timeout=10_000)
        await expect(reset).to_be_hidden()
        armed = await page.evaluate(LOOK_JS)
        assert armed["flight"] == "armed" and armed["level"] == "armed", armed
        assert armed["header"] != disarmed["header"], (armed, disarmed)
        assert armed["mode"] != disarmed["mode"], (armed, disarmed)

        await page.get_by_test_id("takeoff").click()
        await expect(mode).to_have_text("hover", timeout=60_000)
        await page.wait_for_timeout(3000)  # a few seconds of live plots for the pictures
        await assert_the_operator_sees_it(page, MEDIUM, arena)
        await page.screenshot(path=str(IMAGES / "dashboard-1280.png"))
        await page.set_viewport_size(WIDE)
        await assert_the_operator_sees_it(page, WIDE, arena)
        await page.screenshot(path=str(IMAGES / "dashboard-1920.png"))
        await page.set_viewport_size(MEDIUM)

        await page.get_by_test_id("abort").click()
        await expect(mode).to_have_text(re.compile("abort|disarmed"))
        await expect(mode).to_have_text("disarmed", timeout=90_000)
        await expect(last_flight).to_be_visible()
        await expect(last_flight).to_have_attribute("data-ended", "abort")
        await expect(last_flight).to_contain_text("Last flight ended in an abort")
        await expect(last_flight).to_contain_text("asked for with ABORT")
        aborted = await page.evaluate(LOOK_JS)
        assert aborted["flight"] == "ended-abort" and aborted["lastFlight"], aborted
        assert len({disarmed["flight"], armed["flight"], aborted["flight"]}) == 3
        await expect(reset).to_be_visible()
        await assert_the_operator_sees_it(page, MEDIUM, arena)
        await page.screenshot(path=str(IMAGES / "dashboard-1280-aborted.png"))

        # A page opened again says it too: the flight process remembers how it ended.
        await page.reload()
        connection = page.get_by_test_id("connection")
        await expect(connection).to_have_text(re.compile("connected|live again"), timeout=20_000)
        await expect(last_flight).to_have_attribute("data-ended", "abort", timeout=10_000)
        await expect(last_flight).to_contain_text("asked for with ABORT")

        # The line stays until the next arm, which the Reset makes possible at once.
        await reset.click()
        await expect(reason).to_contain_text("world reset:")
        await expect(last_flight).to_be_visible()
        await expect(page.get_by_test_id("arm-blocked")).to_have_text("", timeout=30_000)
        await page.get_by_test_id("arm").click()
        await expect(mode).to_have_text("armed", timeout=10_000)
        await expect(last_flight).to_be_hidden()
        assert (await page.evaluate(LOOK_JS))["flight"] == "armed"
        await page.get_by_test_id("disarm").click()
        await expect(mode).to_have_text("disarmed", timeout=10_000)
        again = await page.evaluate(LOOK_JS)
        assert again["flight"] == "disarmed" and not again["lastFlight"], again
        assert again["header"] == disarmed["header"], (again, disarmed)
        assert not PAGE_ERRORS, PAGE_ERRORS


PATH_PINK = (0xFF, 0x5F, 0xD2)
SQUARE_PATH = {
    "waypoints": [
        {"bar_position": [1.0, 0.0, 1.1]},
        {"bar_position": [1.0, 1.0, 1.4]},
        {"bar_position": [0.0, 1.0, 1.1]},
    ],
    "speed_mps": 0.4,
    "accel_mps2": 0.5,
    "hold_s": 1.0,
}
PATH_PROGRESS = re.compile(
    r"^Path \d\.\d\d m through 3 waypoints in \d+\.\d s: \d+\.\d / \d+\.\d s$"
)
DRAWN_PX_JS = """([selector, points]) => {
    const drawn = JSON.parse(document.querySelector(selector).dataset.arena);
    const [a, b] = selector === "#top-view" ? [0, 1] : [0, 2];
    const scale = (drawn.right - drawn.left) / (drawn.max[0] - drawn.min[0]);
    return points.map((p) => [drawn.left + (p[a] - drawn.min[0]) * scale,
                              drawn.bottom - (p[b] - drawn.min[1]) * scale]);
}"""


def around(points_px: list[list[float]], drawn: dict[str, float], margin_px: float) -> bool:
    """The drawn pixels' centroid lies within the points' box, ``margin_px`` around it."""
    xs, ys = [p[0] for p in points_px], [p[1] for p in points_px]
    inside_x = min(xs) - margin_px <= drawn["x"] <= max(xs) + margin_px
    return inside_x and min(ys) - margin_px <= drawn["y"] <= max(ys) + margin_px


async def test_the_active_path_is_drawn_in_every_view_with_its_progress(
    browser: Browser, tmp_path: Path
) -> None:
    """A path queued in a hover: drawn as a line where its points are in the top, side and
    3D views, its progress said under the active setpoint; gone from all once cleared."""
    views = ("#top-view", "#side-view", "#view3d")
    async with running_service(TOKEN, tmp_path) as service:
        page = await open_dashboard(browser, service, TOKEN)
        async with service.client() as http:
            await service.take_off(http)
            for selector in views:
                assert (await colour_pixels(page, selector, PATH_PINK))["count"] == 0, selector
            (await http.post("/api/path", json=SQUARE_PATH)).raise_for_status()
            progress = page.get_by_test_id("path-progress")
            await expect(progress).to_have_text(PATH_PROGRESS, timeout=15_000)
            path = (await service.status(http)).path
            assert path is not None
            await page.wait_for_timeout(500)  # a few messages drawn since
            for selector in views[:2]:
                drawn = await colour_pixels(page, selector, PATH_PINK)
                points_px = await page.evaluate(DRAWN_PX_JS, [selector, path.points])
                assert drawn["count"] > 50 and around(points_px, drawn, 4.0), (selector, drawn)
            drawn = await colour_pixels(page, "#view3d", PATH_PINK)
            projected = [
                await page.evaluate("p => window.uavbarView3d.project(p)", point)
                for point in path.points
            ]
            assert drawn["count"] > 30 and around(projected, drawn, 4.0), drawn
            await page.screenshot(path=str(IMAGES / "dashboard-path.png"))
            # Cleared mid-path (its flight to the end is test_service's and test_cli_e2e's).
            (await http.delete("/api/setpoints")).raise_for_status()
            await expect(progress).to_have_text("", timeout=15_000)
            await page.wait_for_timeout(500)
            for selector in views:
                assert (await colour_pixels(page, selector, PATH_PINK))["count"] == 0, selector
            (await http.post("/api/land")).raise_for_status()
            await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "landed")
        assert not PAGE_ERRORS, PAGE_ERRORS
