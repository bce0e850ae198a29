"""What a diagnosis writes: report.json (:mod:`.report`), its conclusion in sentences
(:mod:`.conclusion`), report.html (:mod:`.html`), and the autopilot parameters to set
(:mod:`.autopilot_params`)."""
