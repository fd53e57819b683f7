# The shape of the paper's teach and learn trees, with its two timers.
<pl>
    # Teach: answer a query for known knowledge, then cool down for 1000 ticks (TT1).
    <sq>
        <c>(QueryReceived)
        <c>(!_coolDownF)
        <a>(RespondWithKnowledge)
        <tt1>(1000)
            <a>(ResetCoolDown)
        <e>
    <e>
    # Learn: on an unknown condition sequence, query and wait up to 1000 ticks (TT2).
    <sq>
        <c>(UnknownSequence)
        <c>(!_coolDownF)
        <tt2>(1000)
            <a>(QueryAndWait)
        <e>
    <e>
<e>
