# A teacher's knowledge: the four per-colour pick-up skills of the search-and-rescue demo
# robot (1 red, 2 green, 3 yellow, 4 blue), each written flat: its conditions, then its
# actions. A robot that asks about TargetSeen(colour=2) is sent
# <sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>.
<k>(prior)
    <sq>
        <c>(TargetSeen, colour=1)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=1)
    <e>
    <sq>
        <c>(TargetSeen, colour=2)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=2)
    <e>
    <sq>
        <c>(TargetSeen, colour=3)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=3)
    <e>
    <sq>
        <c>(TargetSeen, colour=4)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=4)
    <e>
<e>
