# The search-and-rescue robot's control tree (the paper's Algorithm, with knowledge placeholders).
# Priority runs top to bottom. The simulator merges each robot's prior knowledge into <k>(prior);
# what it learns from other robots is merged into <k>(new) while it runs.
<sl>
    # Critical: avoid collisions, and stand still while asking or teaching.
    <sq>
        <c>(_collisionDetectedF)
        <a>(CollisionAvoidance)
    <e>
    <sq>
        <c>(_waitF)
        <a>(StopWalk)
    <e>
    # Common knowledge: carry a picked-up target to its zone.
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
    # Prior knowledge: the colours this robot was built to rescue.
    <k>(prior)<e>
    # New knowledge: learned from other robots while running.
    <k>(new)<e>
    # Fallback: search.
    <a>(RandomWalk)
<e>
