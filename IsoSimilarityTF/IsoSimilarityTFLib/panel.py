"""The module panel's state without Qt, with one owner: :class:`PanelModel`.

The model holds each piece of the panel's state: the volume it shows (and so that volume's design), the Detail the
shown design is grouped with, the chosen look, the Apply state (idle, running here, running in a child process,
cancelling) and whether the 3D view shows another transfer function than the design. It changes each in one place and
tells its view once per change (a ``show_*`` method of :class:`PanelView`). It alone observes the scene, the
parameter node, the active volume and the shown volume's rendering, with plain VTK observers at explicit priorities
(Slicer's node selector and the parameter node wrapper observe the same objects). The widget
(``IsoSimilarityTF.py``) draws with Qt and forwards clicks; the tests drive the model on a real ``slicer-core`` scene
with the events in Slicer's own order (``Testing/test_panel.py``).
"""

from contextlib import contextmanager
from typing import Callable, Optional

from . import mrml
from .errors import OptionError
from .options import check_options
from .session import AUTO_DETAIL, Cancelled, DesignSession

#: The Apply states: nothing runs; a design runs in this process; in a child process; Cancel was pressed and the
#: design in this process stops at its next progress report.
IDLE, RUNNING_HERE, RUNNING_CHILD, CANCELLING = "idle", "running-here", "running-child", "cancelling"

#: What :meth:`PanelModel.apply` and :meth:`PanelModel.poll_job` say of an Apply: still running (in a child
#: process), done (its design shown; a child's error is raised), cancelled, refused (one already runs, or no volume is
#: selected: nothing started), or its volume was removed from the scene meanwhile (nothing shown).
RUNNING, DONE, CANCELLED, REFUSED, VOLUME_REMOVED = "running", "done", "cancelled", "refused", "volume-removed"

#: Observer priorities (VTK calls higher priorities first). The parameter node's ModifiedEvent is observed after the
#: wrapper's cache observers (priority 0; VTK calls the first one added last, so an equal priority would read the
#: previous value: audit G3). A scene's EndImport is observed twice: first, to note the imported input volume before
#: the node selector rebuilds and writes the scene's first volume into the parameter node (Slicer#7492, audit G1);
#: last, to select that volume again and show its design.
AFTER_CACHES, BEFORE_SELECTOR, AFTER_SELECTOR = -1.0, 100.0, -100.0

#: The panel's parameters (the module's parameter node) and the engine options they set
#: (``design_transfer_function`` keywords); the parameter node takes each one's range, words and default from the
#: options table (``IsoSimilarityTF.py``).
PANEL_OPTIONS = {
    "bins": "n_bins",
    "levels": "levels",
    "crossing": "crossing",
    "normalization": "normalization",
    "preference": "preference",
    "damping": "damping",
    "maxIterations": "max_iter",
    "convergenceIterations": "convergence_iter",
    "maxClasses": "max_classes",
    "background": "background",
    "unconverged": "unconverged",
    "tissues": "tissues",
    "colors": "colors",
    "modality": "modality",
    "gradientOpacity": "gradient_opacity",
}
#: Parameter values that stand for the engine's None: all octree levels, a kind of volume detected from the data.
PANEL_NONE = {"levels": 0, "modality": "auto"}
#: The preference word for "the number in preferenceValue".
PREFERENCE_NUMBER = "number"


def engine_options(parameters) -> dict:
    """The engine's options from the panel's parameters, checked against the options table (once, here: a bad value
    raises :class:`~.errors.OptionError` before anything starts).

    ``tissues`` stays the panel's Detail (an int; the session maps it to a grouping once the classes are known).
    """
    options = {}
    for parameter, option in PANEL_OPTIONS.items():
        value = getattr(parameters, parameter)
        if parameter == "preference" and value == PREFERENCE_NUMBER:
            value = parameters.preferenceValue
        elif parameter in PANEL_NONE and value == PANEL_NONE[parameter]:
            value = None
        options[option] = value
    detail = options.pop("tissues")
    if isinstance(detail, bool) or not isinstance(detail, int) or detail < AUTO_DETAIL:
        raise OptionError(f"the Detail must be {AUTO_DETAIL} (automatic) or a number of tissues; got {detail!r}")
    checked = check_options(options)
    return {**{option: checked[option] for option in options}, "tissues": detail}


# vtkCommand::ModifiedEvent (the parameter node's), without importing VTK here.
_MODIFIED_EVENT = "ModifiedEvent"


def gui_tag(wrapper, tag):
    """The tag ``connectGui`` returned; on Slicer 5.8, whose ``connectGui`` returns None (``wrapper.py:241-253`` at
    v5.8.1; fixed in 5.10.0), the newest key of the wrapper's connector table (``:204-206``), so that
    ``disconnectGui`` undoes the connection there too. Otherwise the old connectors stay connected, and the next
    connection's rebuilt combo boxes make them write their first choice into the parameter node."""
    if tag is None:
        connected = getattr(wrapper, "_parameterGUIs", None)
        if connected:
            return max(connected)
    return tag


class PanelView:
    """What the model tells its view, one method per piece of state (the widget draws with Qt; here they do nothing),
    and the two questions it asks."""

    def show_parameters(self) -> None:
        """The parameter node changed: enable what depends on it (Apply needs a volume, ...)."""

    def show_design(self, design) -> None:
        """The shown volume changed, or its design: the tree, the Detail slider's range, the looks, the similarity
        picture, the hand-over buttons (``design`` None: the panel shows none)."""

    def show_tree(self, design) -> None:
        """The grouping changed: rebuild the tree and the looks (the looks are made per grouping)."""

    def show_rows(self) -> None:
        """Set the tree's editors from the design (an edit was made or refused)."""

    def show_detail_label(self) -> None:
        """The text beside the Detail slider."""

    def show_look(self, name: Optional[str]) -> None:
        """The chosen look (None: no design shown)."""

    def show_apply_state(self, state: str, volume) -> None:
        """The Apply state changed (:data:`IDLE`, :data:`RUNNING_HERE`, ...); ``volume``: the one being designed."""

    def show_outside_change(self, change: Optional[str]) -> None:
        """Whether the 3D view shows another transfer function than the design (see :func:`.mrml.outside_change`;
        None: it shows the design)."""

    def scene_closing(self) -> None:
        """The scene is being closed (the panel shows nothing): let go of the parameter node's GUI."""

    def scene_closed(self) -> None:
        """The scene was closed: follow its new selection node and parameter node."""

    def confirm_overwrite(self, change: str) -> bool:
        """Ask before an edit replaces a transfer function changed outside the module."""
        return True

    def attempt(self, what: str, action: Callable[[], None]) -> None:
        """Run an action of the user's, showing its error (``what``: "regroup" or "edit")."""
        action()


class PanelModel:
    """The panel's state; one per widget.

    Args:
        session: the module's logic (a :class:`~.session.DesignSession`).
        view: the panel's drawing (:class:`PanelView`).
    """

    def __init__(self, session: DesignSession, view: PanelView) -> None:
        self.session = session
        self.view = view
        #: The parameter node wrapper (attributes ``inputVolume`` and ``tissues``), None when disconnected.
        self.parameters = None
        #: The volume whose design the panel shows (None: none).
        self.shown_volume = None
        #: The Detail the shown design is grouped with (None: no design shown; the Detail is then left alone).
        self.detail_shown: Optional[int] = None
        #: The Apply state (:data:`IDLE`, :data:`RUNNING_HERE`, :data:`RUNNING_CHILD`, :data:`CANCELLING`).
        self.apply_state = IDLE
        #: The volume being designed (None when idle).
        self.apply_volume = None
        #: The design being computed in a child process (:class:`~.worker.DesignProcess`).
        self.job = None
        #: How the 3D view differs from the shown design (:func:`.mrml.outside_change`), as last told to the view.
        self.outside_change: Optional[str] = None
        #: The input follows the scene's active volume (the selection node's) until the user picks another volume.
        self.follow_active_volume = True
        self._scene = None
        self._observations = []
        self._parameter_observation = None
        self._selection_node = None
        self._selection_observation = None
        self._rendering_observation = None
        self._imported_input_id = None
        self._writing = 0

    @property
    def running(self) -> bool:
        """An Apply is under way: the panel then ignores the parameter node and the active volume until it ends."""
        return self.apply_state != IDLE

    # Connections ---------------------------------------------------------------------------------------------------
    def observe_scene(self, scene) -> None:
        """Follow the scene's closes and imports (once; :meth:`stop` undoes it)."""
        self._scene = scene
        self._observe(scene, scene.StartCloseEvent, self.on_scene_start_close)
        self._observe(scene, scene.EndCloseEvent, self.on_scene_end_close)
        self._observe(scene, scene.EndImportEvent, self._note_imported_input, BEFORE_SELECTOR)
        self._observe(scene, scene.EndImportEvent, self.on_scene_end_import, AFTER_SELECTOR)

    def observe_selection(self, selection_node) -> None:
        """Follow the active volume of this selection node (the application logic's; again after a scene close, in
        case it is another node)."""
        if selection_node is self._selection_node:
            return
        if self._selection_observation is not None:
            self._selection_node.RemoveObserver(self._selection_observation)
            self._selection_observation = None
        self._selection_node = selection_node
        if selection_node is not None:
            self._selection_observation = selection_node.AddObserver(_MODIFIED_EVENT, self._on_selection_modified)

    def set_parameters(self, parameters, node=None) -> None:
        """Follow a parameter node (``node``: the object whose ModifiedEvent to observe, by default the wrapper's
        ``parameterNode``), or none."""
        if self._parameter_observation is not None:
            self._parameter_observation[0].RemoveObserver(self._parameter_observation[1])
            self._parameter_observation = None
        self.parameters = parameters
        if parameters is not None:
            observed = parameters.parameterNode if node is None else node
            tag = observed.AddObserver(_MODIFIED_EVENT, self._on_modified, AFTER_CACHES)
            self._parameter_observation = (observed, tag)

    def stop(self) -> None:
        """Cancel an Apply and remove every observer (the widget is cleaned up)."""
        self.cancel()
        self.set_parameters(None)
        self.observe_selection(None)
        self._observe_rendering(None)
        for observed, tag in self._observations:
            observed.RemoveObserver(tag)
        self._observations = []

    def _on_modified(self, caller, event) -> None:
        self.refresh()

    def _observe(self, observed, event, method, priority: float = 0.0) -> None:
        tag = observed.AddObserver(event, lambda caller, event: method(), priority)
        self._observations.append((observed, tag))

    def _observe_rendering(self, volume) -> None:
        """Follow the rendering of the shown volume: its display nodes, their property nodes and those nodes'
        transfer functions (the volume sends DisplayModifiedEvent for each), to say at once when the 3D view shows
        another transfer function than the design (a preset, Shift, Synchronize, another property node)."""
        if self._rendering_observation is not None:
            self._rendering_observation[0].RemoveObserver(self._rendering_observation[1])
            self._rendering_observation = None
        if volume is not None:
            tag = volume.AddObserver(volume.DisplayModifiedEvent, self._on_rendering_modified)
            self._rendering_observation = (volume, tag)

    def _on_rendering_modified(self, caller, event) -> None:
        if not self._writing:
            self._check_outside_change()

    @contextmanager
    def _writes(self):
        """The panel writes the shown design into the scene: the rendering's events are not checked one by one
        (an edit sends dozens); the outside change is checked once at the end."""
        self._writing += 1
        try:
            yield
        finally:
            self._writing -= 1
            if not self._writing:
                self._check_outside_change()

    def _check_outside_change(self) -> None:
        change = None
        if self.shown_volume is not None and self.detail_shown is not None:
            current = self.session.volume_node is self.shown_volume
            change = mrml.outside_change(self.shown_volume, self.session.design if current else None)
        if change != self.outside_change:
            self.outside_change = change
            self.view.show_outside_change(change)

    # The active volume -------------------------------------------------------------------------------------------
    def active_volume(self):
        """The scene's active volume if it is a plain scalar volume (the kind the selector lists), else None."""
        node_id = self._selection_node.GetActiveVolumeID() if self._selection_node is not None else None
        node = self._scene.GetNodeByID(node_id) if node_id and self._scene is not None else None
        return node if node is not None and node.GetClassName() == "vtkMRMLScalarVolumeNode" else None

    def select_active_volume(self) -> None:
        """The module is entered: select the active volume if the input follows it or nothing is selected."""
        active = self.active_volume()
        if active is not None and self.parameters is not None:
            if self.follow_active_volume or self.parameters.inputVolume is None:
                self.parameters.inputVolume = active

    def volume_picked(self, node) -> None:
        """The user picked a volume in the selector: the input follows the active volume again only if they picked
        it (or none)."""
        active = self.active_volume()
        self.follow_active_volume = node is None or active is None or node is active

    def _on_selection_modified(self, caller, event) -> None:
        if not self.follow_active_volume or self.parameters is None or self.running:
            return
        active = self.active_volume()
        if active is not None and active is not self.parameters.inputVolume:
            self.parameters.inputVolume = active

    # Following the scene -----------------------------------------------------------------------------------------
    def refresh(self) -> None:
        """The parameter node changed (the user, a script, or a scene import or close): show the selected volume's
        design if it is another volume, and regroup the shown design if the Detail changed."""
        if self.running or self.parameters is None:
            return
        self.view.show_parameters()
        # During an import the design's text node may not be added yet, or added with its .txt file not yet read
        # (vtkMRMLScene::Import reads storable nodes only after adding every node): wait for EndImport.
        if self._scene is not None and self._scene.IsImporting():
            return
        volume = self.parameters.inputVolume
        if volume is not self.shown_volume:
            self.show_volume(volume)
        self.detail_changed()

    def show_volume(self, volume) -> None:
        """Show the design stored for the volume (an earlier run, a saved scene), or none."""
        with self._writes():  # a restore sets the unit distance again
            design = self.session.restore(volume)
        self.show_result(volume, design)

    def _note_imported_input(self) -> None:
        """EndImport, before the node selector: the input volume the imported parameter node selects."""
        node = self.parameters.parameterNode if self.parameters is not None else None
        self._imported_input_id = node.GetNodeReferenceID("inputVolume") if node is not None else None

    def on_scene_end_import(self) -> None:
        """EndImport, after the node selector: the scene's nodes and files are all read now. Select the volume the
        imported parameter node selected (the selector wrote the scene's first volume meanwhile), and show it."""
        imported, self._imported_input_id = self._imported_input_id, None
        if self.parameters is None or self.running:
            return
        node = self._scene.GetNodeByID(imported) if imported and self._scene is not None else None
        if node is not None and node is not self.parameters.inputVolume:
            self.parameters.inputVolume = node
        self.show_volume(self.parameters.inputVolume)

    def on_scene_start_close(self) -> None:
        """A design under way would be written into the closing scene: it is stopped; the panel shows nothing."""
        self.cancel()
        self.session.forget()
        self.show_result(None, None)
        self.view.scene_closing()

    def on_scene_end_close(self) -> None:
        self.follow_active_volume = True
        self.view.scene_closed()

    # The shown design --------------------------------------------------------------------------------------------
    def show_result(self, volume, design) -> None:
        """A design (or none) is the volume's: show it in the panel (after an Apply, or a restore)."""
        if volume is not self.shown_volume:
            self._observe_rendering(volume)
        self.shown_volume = volume
        self.detail_shown = self.session.detail() if design is not None else None
        # The slider's range first: it must not clamp the grouping written next.
        self.view.show_design(design)
        if design is not None and self.parameters is not None:
            self.parameters.tissues = self.detail_shown
        self.view.show_detail_label()
        self.view.show_look(self.look())
        self._check_outside_change()

    def shown_design(self):
        """The shown volume's design, made the session's current one again if a script made another volume's
        current behind the panel; None when the panel shows no design (then nothing acts on one)."""
        if self.shown_volume is None or self.detail_shown is None:
            return None
        if self.session.volume_node is not self.shown_volume:
            with self._writes():
                design = self.session.restore(self.shown_volume)
            if design is None:  # its design node was deleted meanwhile
                self.show_result(self.shown_volume, None)
            return design
        return self.session.design

    def detail_design(self):
        """The design the Detail label describes (None when the panel shows none)."""
        return (
            self.session.design
            if self.detail_shown is not None and self.session.volume_node is self.shown_volume
            else None
        )

    def detail(self) -> int:
        return self.parameters.tissues if self.parameters is not None else AUTO_DETAIL

    def look(self) -> Optional[str]:
        """The shown design's chosen look (None: no design shown)."""
        design = self.detail_design()
        return design.chosen_look if design is not None else None

    # The Detail --------------------------------------------------------------------------------------------------
    def detail_changed(self) -> None:
        """Regroup the shown design when the parameter node's Detail is not the one it is grouped with."""
        detail = self.parameters.tissues
        if detail == self.detail_shown or self.shown_design() is None:
            self.view.show_detail_label()
            return
        self.detail_shown = detail
        if self._confirm():
            with self._writes():
                self.view.attempt("regroup", lambda: self.session.regroup(detail))
        # The design's own setting: a count past its classes becomes its class count; if the user kept the other
        # transfer function, the Detail goes back to the design's grouping.
        self.detail_shown = self.session.detail()
        self.parameters.tissues = self.detail_shown
        self.view.show_tree(self.session.design)
        self.view.show_detail_label()
        self.view.show_look(self.look())

    # Apply -------------------------------------------------------------------------------------------------------
    def _set_apply_state(self, state: str, volume=None) -> None:
        self.apply_state = state
        self.apply_volume = volume
        self.view.show_apply_state(state, volume)
        if state == IDLE:
            self.refresh()  # what the parameter node selected meanwhile

    def apply(self, progress: Callable[[str, float, str], None]) -> str:
        """Design the selected volume with the panel's options: in this process when it is quick (then
        ``progress(stage, fraction, message)`` draws each report and may let Cancel be pressed), else in a child
        process (then :meth:`poll_job`). The Apply state is set before anything can process events, so a second
        Apply meanwhile is refused.

        Returns :data:`DONE` (the design is shown), :data:`RUNNING` (a child process designs it),
        :data:`CANCELLED`, :data:`VOLUME_REMOVED` or :data:`REFUSED`. A bad option raises
        :class:`~.errors.OptionError` before anything starts; the engine's errors are raised (nothing changed).
        """
        volume = self.parameters.inputVolume if self.parameters is not None else None
        if self.running or volume is None:
            return REFUSED
        options = engine_options(self.parameters)
        if not self.session.runs_in_process(volume, options):
            self._set_apply_state(RUNNING_CHILD, volume)
            try:
                self.job = self.session.start(volume, options)
            except BaseException:
                self._set_apply_state(IDLE)
                raise
            return RUNNING
        self._set_apply_state(RUNNING_HERE, volume)

        def report(stage: str, fraction: float, message: str) -> None:
            progress(stage, fraction, message)
            if self.apply_state == CANCELLING or volume.GetScene() is None:
                raise Cancelled()

        try:
            with self._writes():
                design = self.session.run(volume, options, progress=report)
            self.show_result(volume, design)
            return DONE
        except Cancelled:
            return CANCELLED if volume.GetScene() is not None else VOLUME_REMOVED
        finally:
            self._set_apply_state(IDLE)

    def poll_job(self) -> tuple:
        """``(reports, outcome)``: the child's progress reports since the last call and :data:`RUNNING`,
        :data:`DONE` (its design is shown; the child's error is raised), :data:`VOLUME_REMOVED`, or
        :data:`CANCELLED` when no job runs."""
        job = self.job
        if job is None:
            return [], CANCELLED
        finished = not job.running
        reports = job.poll()
        if not finished:
            return reports, RUNNING
        volume = self.apply_volume
        self.job = None
        try:
            if volume.GetScene() is None:
                job.close()
                return reports, VOLUME_REMOVED
            with self._writes():
                design = self.session.finish(volume, job)
            self.show_result(volume, design)
            return reports, DONE
        finally:
            self._set_apply_state(IDLE)

    def cancel(self) -> None:
        """Cancel the Apply: a child process is ended now and its files removed; a design in this process stops at
        its next progress report."""
        if self.apply_state == RUNNING_HERE:
            self._set_apply_state(CANCELLING, self.apply_volume)
        elif self.apply_state == RUNNING_CHILD:
            job, self.job = self.job, None
            if job is not None:
                job.close()
            self._set_apply_state(IDLE)

    # Edits, looks and hand-overs ---------------------------------------------------------------------------------
    def _confirm(self) -> bool:
        """Whether an edit may write the design into the 3D view; when the user agrees to replace a transfer function
        changed outside (a preset copied in, Shift, Synchronize), the design's shading and gradient opacity come back
        too (a preset's ``CopyContent`` replaced them)."""
        change = self.session.outside_change()
        if change is None:
            return True
        if not self.view.confirm_overwrite(change):
            return False
        if change == mrml.CHANGE_EDITED:
            with self._writes():
                self.session.restyle()
        return True

    def edit(self, action: Callable[[], None]) -> None:
        """One edit of the shown design (a session method that rewrites the transfer function), after asking."""
        if self.shown_design() is not None and self._confirm():
            with self._writes():
                self.view.attempt("edit", action)
        self.view.show_rows()

    def use_look(self, name: str) -> None:
        """Show a look of the gallery (an edit: it replaces the colours, opacities and visibility)."""
        self.edit(lambda: self.session.use_look(name))
        self.view.show_look(self.look())

    def hand_over(self, action: Callable[[], object]):
        """Run a hand-over (export, segments, preset) on the shown volume's design; None when none is shown."""
        if self.shown_design() is None:
            return None
        return action()
