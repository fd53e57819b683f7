# The search-and-rescue control tree of the KT-BT paper, written with knowledge placeholders.
# Priority runs top to bottom: critical subtrees first, the fallback last.
<sl>
    # Critical: avoid collisions, and stand still while querying or teaching.
    <sq>
        <c>(_collisionDetectedF)
        <a>(CollisionAvoidance)
    <e>
    <sq>
        <c>(_waitF)
        <a>(StopWalk)
    <e>
    # Common knowledge: carry a picked-up target to its colour's zone.
    <k>(common)
        <sq>
            <c>(_treasureOnBoardF)
            <sl>
                <sq>
                    <c>(_inZoneF)
                    <a>(PlaceTreasure)
                <e>
                <sq>
                    <c>(!_inZoneF)
                    <a>(WalkToCollection)
                <e>
            <e>
        <e>
    <e>
    # Prior knowledge: this robot was built knowing how to rescue red targets.
    <k>(prior)
        <sq>
            <c>(TargetSeen, colour=1)
            <a>(PickTreasure)
            <a>(AssignCollectionPoint, colour=1)
        <e>
    <e>
    # New knowledge: subtrees learned from other robots are merged here.
    <k>(new)<e>
    # Fallback.
    <a>(RandomWalk)
<e>
