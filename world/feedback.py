"""The feedback sentences a robot's agent reads after each skill (after the paper's Table III).

One function per row of the table: each takes what the skill measured and says it plainly: what
failed, why, and the measured quantities (distances, Alice's x/y offsets, valid stand pose
indices). Like the paper's, the sentences give causes and numbers, never advice. What would tell
a robot what to do next (navigate somewhere instead, open or place something first, try again)
and the lists of names it could have used instead are the `feedback_advice` aid
(mhrc.core.fidelity.AIDS): the functions that have such help take `advice=True` to append it, and
without it they say the same sentence without the help.
"""

from __future__ import annotations


def _names(names: list[str] | tuple[str, ...], empty: str = "none") -> str:
    return ", ".join(names) if names else empty


# --------------------------------------------------------------------------- any skill


def not_capable(robot: str, skill: str, skills: tuple[str, ...]) -> str:
    return f"{robot.capitalize()} cannot {skill}: its skills are {_names(skills)}."


def no_such_robot(robot: str, robots: tuple[str, ...]) -> str:
    return f"There is no robot {robot!r} in this world; robots: {_names(robots)}."


def broken_down(skill: str, ticks: int) -> str:
    """A scenario's breakdown (world/dynamics.py): the robot can only communicate and wait."""
    return (
        f"You cannot {skill}: you are broken down for {ticks} more step{'s' if ticks != 1 else ''}; "
        "until then you can only communicate and wait."
    )


def waited() -> str:
    return "You waited."


# --------------------------------------------------------------------------- navigate / move


def unknown_furniture(name: str, furniture: list[str], *, advice: bool = False) -> str:
    """`furniture`: the names the robot could use (listed only with the feedback_advice aid)."""
    text = f"There is no {name!r} in your scene graph"
    return text + (f"; furniture: {_names(furniture)}." if advice else ".")


def not_navigable(name: str, where: str | None, *, advice: bool = False) -> str:
    """`where`: the furniture to go to instead (said only with the feedback_advice aid)."""
    text = f"{name} has no stand pose: it is not something you can navigate to."
    return text + (f" Navigate to {where} instead." if where and advice else "")


def stand_pose_invalid(name: str, count: int, index: int) -> str:
    return f"{name} has {count} stand pose(s), numbered 0 to {count - 1}; there is no stand pose {index}."


def start_invalid() -> str:
    return "Navigation failed: your start pose is on an obstacle or off the map."


def goal_invalid(name: str, index: int) -> str:
    return f"Navigation failed: stand pose {index} of {name} is on an obstacle or off the map."


def occupied(name: str, index: int, occupant: str, *, advice: bool = False) -> str:
    """One robot per stand pose: another robot (`occupant`) stands at the goal, an obstacle on it."""
    who = occupant.capitalize()
    text = f"Navigation failed: stand pose {index} of {name} is occupied by {who}."
    return text + (f" Try another stand pose of {name}, or wait until {who} leaves." if advice else "")


def no_path(name: str, index: int) -> str:
    return f"Navigation failed: there is no collision-free path to stand pose {index} of {name}."


def reached(
    name: str,
    index: int,
    seen: list[str] | None,
    *,
    container: bool = False,
    can_open: bool = True,
    advice: bool = False,
) -> str:
    """`seen` is None for a closed container (its inside cannot be seen): the paper says opening is
    needed to see inside; telling a robot that can open it to do so is the feedback_advice aid."""
    text = f"You reached stand pose {index} of {name}."
    if seen is None:
        if can_open and advice:
            return text + f" {name} is closed: open it to see what is inside."
        return text + f" {name} is closed: what is inside cannot be seen until it is opened."
    if container:
        return text + (f" In the open {name}: {', '.join(seen)}." if seen else f" The open {name} is empty.")
    return text + (f" On {name}: {', '.join(seen)}." if seen else f" There is nothing on {name}.")


def off_target(name: str, index: int, distance: float, pose: tuple[float, float], *, advice: bool = False) -> str:
    text = (
        f"Navigation ended off target: your base stopped {distance:.2f} m from stand pose {index} of {name}, "
        f"at x={pose[0]:.2f}, y={pose[1]:.2f}."
    )
    return text + (f" Navigate to stand pose {index} of {name} again." if advice else "")


def move_off_target(dx: float, dy: float, distance: float, moved: tuple[float, float]) -> str:
    return (
        f"Move ended off target: your base moved by dx={moved[0]:.2f} m, dy={moved[1]:.2f} m instead of "
        f"dx={dx:.2f}, dy={dy:.2f}, stopping {distance:.2f} m from the goal."
    )


def move_too_long(distance: float, limit: float) -> str:
    return f"Move failed: {distance:.2f} m is more than the {limit:.1f} m one move may cover."


def move_blocked(dx: float, dy: float) -> str:
    return f"Move failed: moving by dx={dx:.2f}, dy={dy:.2f} would hit an obstacle or leave the map."


def moved(dx: float, dy: float) -> str:
    return f"You moved by dx={dx:.2f} m, dy={dy:.2f} m."


# --------------------------------------------------------------------------- open


def not_openable(name: str) -> str:
    return f"{name} cannot be opened: it has no door or drawer."


def already_open(name: str) -> str:
    return f"{name} is already open."


def hands_full_to_open(name: str, held: str, *, advice: bool = False) -> str:
    text = f"You cannot open {name}: your gripper holds {held}."
    return text + (f" Place {held} before opening {name}." if advice else "")


def handle_out_of_reach(name: str, distance: float, *, mobile: bool = True, advice: bool = False) -> str:
    text = f"The handle of {name} is out of your arm's reach: it is {distance:.2f} m from your arm base."
    return text + (f" Navigate to a stand pose of {name} first." if mobile and advice else "")


def no_grip(name: str, distance: float) -> str:
    return f"Your arm found no way to grip the handle of {name} from where your base stands ({distance:.2f} m from your arm base): it stays closed."


def pull_failed(name: str) -> str:
    return f"Your arm could not follow the handle of {name}: it stays closed."


def _at(pos: tuple[float, float, float]) -> str:
    return f"({pos[0]:.2f}, {pos[1]:.2f}, {pos[2]:.2f})"


def opened(name: str, inside: list[tuple[str, tuple[float, float, float]]]) -> str:
    """`inside`: each object in the opened container and its position (m, to the cm)."""
    if not inside:
        return f"You opened {name}; it is empty."
    return f"You opened {name}. Inside: {', '.join(f'{n} at {_at(pos)}' for n, pos in inside)}."


# --------------------------------------------------------------------------- pick


def gripper_full(held: str, *, advice: bool = False) -> str:
    return f"Your gripper already holds {held}" + ("; place it first." if advice else ".")


def object_unknown(name: str, known: list[str], *, advice: bool = False) -> str:
    """`known`: the objects the robot knows of (listed only with the feedback_advice aid)."""
    text = f"There is no {name!r} in your scene graph"
    return text + (f"; objects you know: {_names(known)}." if advice else ".")


def held_by_other(name: str, robot: str) -> str:
    return f"{name} is held by {robot}; you cannot pick it now."


def in_closed_container(name: str, container: str, *, can_open: bool = True, advice: bool = False) -> str:
    return f"{name} is inside {container}, which is closed" + (": open it first." if can_open and advice else ".")


def too_far(
    name: str, distance: float, offset: tuple[float, float] | None = None, fix: tuple[float, float] | None = None
) -> str:
    """`offset`: the object from the base centre along world x and y (mobile manipulators);
    `fix`: the solved corrective move (the solved_move aid)."""
    text = (
        f"The end effector cannot reach {name}: it is {distance:.2f} m away from the closest pose your arm can get to."
    )
    if offset is not None:
        text += f" {name} is at offset x={offset[0]:+.2f} m, y={offset[1]:+.2f} m from your base centre."
    if fix is not None:
        text += f" Moving your base by dx={fix[0]:.2f}, dy={fix[1]:.2f} would bring it within a good grasping distance."
    return text


def config_invalid(what: str, which: str) -> str:
    return f"The arm planner found the {which} configuration invalid (in collision) for {what}."


def no_goal_configuration(what: str, error: float) -> str:
    """Inverse kinematics came within `error` of the point (less than the sentence's centimetre)
    but found no verified pose there: the goal configuration is invalid, not too far away."""
    return f"The arm planner found no valid goal configuration for {what}: the closest pose it found leaves the end effector {error * 1000:.0f} mm off."


def plan_failed(what: str) -> str:
    return f"The arm planner found no collision-free motion to {what}."


def picked(name: str) -> str:
    return f"You picked up {name}."


# --------------------------------------------------------------------------- place


def gripper_empty(name: str) -> str:
    return f"Your gripper is empty: there is no {name} to place."


def wrong_object(held: str, named: str) -> str:
    return f"You hold {held}, not {named}."


def location_unknown(name: str, places: list[str], *, advice: bool = False) -> str:
    """`places`: where the robot may place (listed only with the feedback_advice aid)."""
    return f"There is no place called {name!r}" + (f"; places: {_names(places)}." if advice else ".")


def not_a_surface(name: str, places: list[str], *, advice: bool = False) -> str:
    text = f"Objects cannot be placed on or into {name}: it has no place pose."
    return text + (f" Places: {_names(places)}." if advice else "")


def no_free_spot(name: str) -> str:
    return f"There is no free spot left on {name}."


def place_out_of_reach(name: str, distance: float, *, mobile: bool = True, advice: bool = False) -> str:
    text = f"No free spot on {name} is within your arm's reach (the nearest is {distance:.2f} m from your arm base)."
    if mobile:
        return text + (f" Navigate to a stand pose of {name} first." if advice else "")
    return text + " Your arm is mounted where it stands: only places within its reach can take the object."


def not_a_finisher(name: str, location: str, table: str, finisher: str, *, advice: bool = False) -> str:
    """The paper's task constraint (only Bob finishes the task); where to put the object instead is the feedback_advice aid."""
    who = finisher.capitalize()
    if not advice:
        return f"Only {who} places objects on {location}."
    return f"Only {who} places objects on {location}: place {name} on {table} within {who}'s reach for {who} to finish the task."


def place_failed(name: str, location: str, rest: str | None, pos: tuple[float, float, float]) -> str:
    """`rest`: what the released object came to rest on (None: the floor)."""
    where = f"on {rest}" if rest is not None else "on the floor"
    return f"{name} did not end up on {location}: it came to rest {where} at {_at(pos)}."


def placed(name: str, location: str) -> str:
    return f"You placed {name} in the tray." if location == "tray" else f"You placed {name} on {location}."
