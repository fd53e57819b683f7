# The green pick-up skill, as a teacher sends it: merge it with
#   ktbt merge examples/sar_control.sbt examples/knowledge/green.sbt --when 'TargetSeen(colour=2)'
<sq>
    <a>(PickTreasure)
    <a>(AssignCollectionPoint, colour=2)
<e>
